#pragma once
// The PLUS configuration reader's XML helpers (formats/plus_config.cpp and
// formats/plus_config_calibration.cpp): the file with its line numbers, an
// element's attributes read and checked one by one, PLUS's number syntax.
// Not for other files.
#include <array>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <pugixml.hpp>
#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "core/io_util.hpp"
#include "formats/plus_config.hpp"

namespace pp5::plusxml {


inline bool equalsNoCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (std::toupper(static_cast<unsigned char>(a[i])) != std::toupper(static_cast<unsigned char>(b[i]))) return false;
  return true;
}

inline bool isSpace(char ch) { return ch == ' ' || ch == '\t' || ch == '\n' || ch == '\r' || ch == '\f' || ch == '\v'; }

inline std::vector<std::string_view> splitWords(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && isSpace(s[i])) ++i;
    std::size_t j = i;
    while (j < s.size() && !isSpace(s[j])) ++j;
    if (j > i) out.push_back(s.substr(i, j - i));
    i = j;
  }
  return out;
}

inline std::string_view trim(std::string_view s) {
  while (!s.empty() && isSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && isSpace(s.back())) s.remove_suffix(1);
  return s;
}

// from_chars rejects the leading '+' that some writers emit.
inline std::string_view dropPlus(std::string_view tok) {
  if (tok.size() > 1 && tok.front() == '+' && tok[1] != '-' && tok[1] != '+') tok.remove_prefix(1);
  return tok;
}

inline bool parseDouble(std::string_view tok, double& x) {
  tok = dropPlus(tok);
  const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), x);
  return ec == std::errc() && end == tok.data() + tok.size() && std::isfinite(x);
}

inline bool parseInt(std::string_view tok, int& x) {
  tok = dropPlus(tok);
  const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), x);
  return ec == std::errc() && end == tok.data() + tok.size();
}

// The parsed file: its text (to turn byte offsets into line numbers) and tree.
struct XmlFile {
  std::string path;
  std::string text;
  pugi::xml_document doc;

  long lineAt(std::ptrdiff_t offset) const {
    if (offset < 0) return 0;
    const auto end = text.begin() + std::min<std::ptrdiff_t>(offset, static_cast<std::ptrdiff_t>(text.size()));
    return 1 + static_cast<long>(std::count(text.begin(), end, '\n'));
  }
  long lineOf(const pugi::xml_node& n) const { return lineAt(n.offset_debug()); }
};

template <typename... Args>
[[noreturn]] void failAt(const XmlFile& f, const pugi::xml_node& n, fmt::format_string<Args...> fs, Args&&... args) {
  const long line = f.lineOf(n);
  const std::string msg = fmt::format(fs, std::forward<Args>(args)...);
  if (line > 0) inputErrorAt(f.path, line, "{}", msg);
  inputError(f.path, "{}", msg);
}

// Reads the attributes of one element, naming the element in every error.
class ElementReader {
public:
  ElementReader(const XmlFile& file, pugi::xml_node node, std::string label)
      : file_(file), node_(node), label_(std::move(label)) {}

  template <typename... Args>
  [[noreturn]] void fail(fmt::format_string<Args...> fs, Args&&... args) const {
    failAt(file_, node_, "{}: {}", label_, fmt::format(fs, std::forward<Args>(args)...));
  }

  const char* raw(const char* name) const {
    const pugi::xml_attribute a = node_.attribute(name);
    return a ? a.value() : nullptr;
  }
  bool has(const char* name) const { return static_cast<bool>(node_.attribute(name)); }

  std::optional<std::string> string(const char* name) const {
    const char* v = raw(name);
    if (!v) return std::nullopt;
    return std::string(v);
  }

  // A string that, when given, must not be blank.
  std::optional<std::string> name(const char* attr) const {
    auto v = string(attr);
    if (v && trim(*v).empty()) fail("{} is empty", attr);
    if (v) *v = std::string(trim(*v));
    return v;
  }

  template <std::size_t N>
  std::optional<std::array<double, N>> doubles(const char* name) const {
    const char* v = raw(name);
    if (!v) return std::nullopt;
    const auto words = splitWords(v);
    std::array<double, N> out{};
    for (std::size_t i = 0; i < words.size(); ++i) {
      double x = 0.0;
      if (!parseDouble(words[i], x)) fail("{} '{}': '{}' is not a finite number", name, trim(v), words[i]);
      if (i < N) out[i] = x;
    }
    if (words.size() != N) fail("{} '{}' has {} numbers, expected {}", name, trim(v), words.size(), N);
    return out;
  }

  template <std::size_t N>
  std::optional<std::array<int, N>> ints(const char* name) const {
    const char* v = raw(name);
    if (!v) return std::nullopt;
    const auto words = splitWords(v);
    std::array<int, N> out{};
    for (std::size_t i = 0; i < words.size(); ++i) {
      int x = 0;
      if (!parseInt(words[i], x)) fail("{} '{}': '{}' is not an integer", name, trim(v), words[i]);
      if (i < N) out[i] = x;
    }
    if (words.size() != N) fail("{} '{}' has {} numbers, expected {}", name, trim(v), words.size(), N);
    return out;
  }

  std::optional<double> real(const char* name) const {
    auto a = doubles<1>(name);
    if (!a) return std::nullopt;
    return (*a)[0];
  }
  std::optional<int> integer(const char* name) const {
    auto a = ints<1>(name);
    if (!a) return std::nullopt;
    return (*a)[0];
  }

  // One of the listed words (case-insensitive, as PLUS matches them). `shown`
  // lists the values named in the error; aliases may be accepted beyond them.
  template <typename E>
  std::optional<E> choice(const char* name, std::initializer_list<std::pair<const char*, E>> options,
                          const char* shown) const {
    const char* v = raw(name);
    if (!v) return std::nullopt;
    const std::string_view t = trim(v);
    for (const auto& [word, value] : options)
      if (equalsNoCase(t, word)) return value;
    fail("{} '{}' is not one of {}", name, t, shown);
  }

  void warnUnknown(std::initializer_list<const char*> known) const {
    for (const pugi::xml_attribute& a : node_.attributes()) {
      const bool ok = std::any_of(known.begin(), known.end(), [&](const char* k) { return std::strcmp(k, a.name()) == 0; });
      if (!ok)
        spdlog::warn("{}:{}: {}: attribute {} is not used by PLUS's volume reconstruction; ignored", file_.path,
                     file_.lineOf(node_), label_, a.name());
    }
  }

  pugi::xml_node node() const { return node_; }
  const XmlFile& file() const { return file_; }

private:
  const XmlFile& file_;
  pugi::xml_node node_;
  std::string label_;
};

inline void loadXml(XmlFile& f) {
  io::checkInputFile(f.path);
  std::ifstream in(f.path, std::ios::binary);
  if (!in) inputError(f.path, "cannot open: {}", std::strerror(errno));
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) inputError(f.path, "cannot read: {}", std::strerror(errno));
  f.text = ss.str();
  // load_buffer keeps byte offsets of the text as given, so errors can name lines.
  const pugi::xml_parse_result r =
      f.doc.load_buffer(f.text.data(), f.text.size(), pugi::parse_default, pugi::encoding_utf8);
  if (!r) {
    const long line = f.lineAt(r.offset);
    inputErrorAt(f.path, line, "malformed XML: {} (byte offset {})", r.description(), r.offset);
  }
}

// The calibration's elements (formats/plus_config_calibration.cpp).
PlusSegmentation readSegmentation(const XmlFile& f, pugi::xml_node n);
PlusPhantomDefinition readPhantomDefinition(const XmlFile& f, pugi::xml_node n);

}  // namespace pp5::plusxml
