#include "core/config.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <sstream>
#include <string_view>

#include <fmt/format.h>
#include <toml++/toml.h>

#include "core/error.hpp"
#include "core/io_util.hpp"

namespace pp5 {
namespace {

std::string formatDouble(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  std::string s = fmt::format("{}", v);
  // TOML reads "1" as an integer; keep floats recognisable as floats.
  if (s.find_first_of(".eE") == std::string::npos) s += ".0";
  return s;
}

std::string quote(const std::string& s) {
  std::ostringstream os;
  os << toml::value<std::string>(s);
  return os.str();
}

template <typename T>
std::string formatArray(const T* v, int n, std::string (*one)(const T&)) {
  std::string s = "[";
  for (int i = 0; i < n; ++i) s += (i ? ", " : "") + one(v[i]);
  return s + "]";
}
std::string fmtD(const double& d) { return formatDouble(d); }
std::string fmtI(const int& i) { return std::to_string(i); }

// Reads a number (integer or float) from a node.
std::optional<double> asNumber(const toml::node& n) {
  if (auto f = n.as_floating_point()) return f->get();
  if (auto i = n.as_integer()) return static_cast<double>(i->get());
  return std::nullopt;
}

template <typename Vec>
std::string readFloatArray(const toml::node& n, Vec* out, int len, double lo, double hi) {
  const auto* arr = n.as_array();
  if (!arr || static_cast<int>(arr->size()) != len) return fmt::format("must be an array of {} numbers", len);
  Vec v{};
  for (int i = 0; i < len; ++i) {
    auto x = asNumber(*arr->get(static_cast<std::size_t>(i)));
    if (!x) return fmt::format("must be an array of {} numbers", len);
    if (!(*x >= lo && *x <= hi)) return fmt::format("element {} = {} is out of range [{}, {}]", i, *x, lo, hi);
    v[i] = *x;
  }
  *out = v;
  return "";
}

template <typename Vec>
std::string readIntArray(const toml::node& n, Vec* out, int len, int lo, int hi) {
  const auto* arr = n.as_array();
  if (!arr || static_cast<int>(arr->size()) != len) return fmt::format("must be an array of {} integers", len);
  Vec v{};
  for (int i = 0; i < len; ++i) {
    const auto* x = arr->get(static_cast<std::size_t>(i))->as_integer();
    if (!x) return fmt::format("must be an array of {} integers", len);
    if (x->get() < lo || x->get() > hi)
      return fmt::format("element {} = {} is out of range [{}, {}]", i, x->get(), lo, hi);
    v[i] = static_cast<int>(x->get());
  }
  *out = v;
  return "";
}

}  // namespace

void ConfigSchema::section(const std::string& name, const std::string& doc) { sections_.push_back({name, doc}); }

void ConfigSchema::add(Entry e) {
  for (const auto& x : entries_) PP5_CHECK(x.key != e.key);
  e.reset();
  entries_.push_back(std::move(e));
}

void ConfigSchema::option(const std::string& key, bool* field, bool def, const std::string& doc) {
  add({key, "bool", def ? "true" : "false", "", doc, [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         const auto* b = n.as_boolean();
         if (!b) return "must be true or false";
         *field = b->get();
         return "";
       },
       [=] { return std::string(*field ? "true" : "false"); }});
}

void ConfigSchema::option(const std::string& key, int* field, int def, int lo, int hi, const std::string& doc) {
  add({key, "integer", std::to_string(def), fmt::format("{} .. {}", lo, hi), doc, [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         const auto* i = n.as_integer();
         if (!i) return "must be an integer";
         if (i->get() < lo || i->get() > hi) return fmt::format("= {} is out of range [{}, {}]", i->get(), lo, hi);
         *field = static_cast<int>(i->get());
         return "";
       },
       [=] { return std::to_string(*field); }});
}

void ConfigSchema::option(const std::string& key, std::uint64_t* field, std::uint64_t def, std::uint64_t lo,
                          std::uint64_t hi, const std::string& doc) {
  add({key, "integer", std::to_string(def), fmt::format("{} .. {}", lo, hi), doc, [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         const auto* i = n.as_integer();
         if (!i) return "must be an integer";
         if (i->get() < 0 || static_cast<std::uint64_t>(i->get()) < lo || static_cast<std::uint64_t>(i->get()) > hi)
           return fmt::format("= {} is out of range [{}, {}]", i->get(), lo, hi);
         *field = static_cast<std::uint64_t>(i->get());
         return "";
       },
       [=] { return std::to_string(*field); }});
}

void ConfigSchema::option(const std::string& key, double* field, double def, double lo, double hi,
                          const std::string& doc) {
  add({key, "float", formatDouble(def), fmt::format("{} .. {}", lo, hi), doc, [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         auto x = asNumber(n);
         if (!x) return "must be a number";
         if (!(*x >= lo && *x <= hi)) return fmt::format("= {} is out of range [{}, {}]", *x, lo, hi);
         *field = *x;
         return "";
       },
       [=] { return formatDouble(*field); }});
}

void ConfigSchema::option(const std::string& key, std::string* field, const std::string& def,
                          const std::string& doc) {
  add({key, "string", quote(def), "", doc, [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         const auto* s = n.as_string();
         if (!s) return "must be a string";
         *field = s->get();
         return "";
       },
       [=] { return quote(*field); }});
}

void ConfigSchema::choice(const std::string& key, std::string* field, const std::string& def,
                          const std::vector<std::string>& choices, const std::string& doc) {
  const auto it = std::find(choices.begin(), choices.end(), def);
  PP5_CHECK(it != choices.end());
  choiceIndex(
      key, choices, static_cast<std::size_t>(it - choices.begin()), [=](std::size_t i) { *field = choices[i]; },
      [=] {
        return static_cast<std::size_t>(std::find(choices.begin(), choices.end(), *field) - choices.begin());
      },
      doc);
}

void ConfigSchema::choiceIndex(const std::string& key, const std::vector<std::string>& choices, std::size_t def,
                               std::function<void(std::size_t)> set, std::function<std::size_t()> get,
                               const std::string& doc) {
  PP5_CHECK_LT(def, choices.size());
  std::string list;
  for (const auto& c : choices) list += (list.empty() ? "" : ", ") + c;
  add({key, "string", quote(choices[def]), "one of: " + list, doc, [=] { set(def); },
       [=](const toml::node& n) -> std::string {
         const auto* s = n.as_string();
         if (!s) return "must be a string";
         const auto it = std::find(choices.begin(), choices.end(), s->get());
         if (it == choices.end()) return fmt::format("= \"{}\" is not one of: {}", s->get(), list);
         set(static_cast<std::size_t>(it - choices.begin()));
         return "";
       },
       [=] {
         const std::size_t i = get();
         return quote(i < choices.size() ? choices[i] : std::string("?"));
       }});
}

void ConfigSchema::option(const std::string& key, glm::dvec3* field, glm::dvec3 def, double lo, double hi,
                          const std::string& doc) {
  add({key, "[float, float, float]", formatArray(&def[0], 3, fmtD), fmt::format("each {} .. {}", lo, hi), doc,
       [=] { *field = def; }, [=](const toml::node& n) { return readFloatArray(n, field, 3, lo, hi); },
       [=] { return formatArray(&(*field)[0], 3, fmtD); }});
}

void ConfigSchema::option(const std::string& key, glm::dvec2* field, glm::dvec2 def, double lo, double hi,
                          const std::string& doc) {
  add({key, "[float, float]", formatArray(&def[0], 2, fmtD), fmt::format("each {} .. {}", lo, hi), doc,
       [=] { *field = def; }, [=](const toml::node& n) { return readFloatArray(n, field, 2, lo, hi); },
       [=] { return formatArray(&(*field)[0], 2, fmtD); }});
}

void ConfigSchema::option(const std::string& key, glm::ivec3* field, glm::ivec3 def, int lo, int hi,
                          const std::string& doc) {
  add({key, "[int, int, int]", formatArray(&def[0], 3, fmtI), fmt::format("each {} .. {}", lo, hi), doc,
       [=] { *field = def; }, [=](const toml::node& n) { return readIntArray(n, field, 3, lo, hi); },
       [=] { return formatArray(&(*field)[0], 3, fmtI); }});
}

namespace {

std::string formatPoints(const std::vector<glm::dvec4>& pts, int width) {
  std::string s = "[";
  for (std::size_t i = 0; i < pts.size(); ++i) s += (i ? ", " : "") + formatArray(&pts[i][0], width, fmtD);
  return s + "]";
}

std::string formatStrings(const std::vector<std::string>& v) {
  std::string s = "[";
  for (std::size_t i = 0; i < v.size(); ++i) s += (i ? ", " : "") + quote(v[i]);
  return s + "]";
}

}  // namespace

void ConfigSchema::option(const std::string& key, std::vector<glm::dvec4>* field, const std::vector<glm::dvec4>& def,
                          int width, double lo, double hi, bool ascending, const std::string& doc) {
  PP5_CHECK(width >= 2 && width <= 4);
  PP5_CHECK(!def.empty());
  const std::string type = fmt::format("list of [{}]", width == 2 ? "float, float" : width == 3 ? "float, float, float"
                                                                                                 : "float, float, float, float");
  add({key, type, formatPoints(def, width),
       fmt::format("each {} .. {}{}", lo, hi, ascending ? "; first components increasing" : ""), doc,
       [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         const auto* arr = n.as_array();
         if (!arr || arr->empty()) return fmt::format("must be a non-empty array of [{} numbers] points", width);
         std::vector<glm::dvec4> pts;
         for (std::size_t i = 0; i < arr->size(); ++i) {
           glm::dvec4 p(0.0);
           const std::string e = readFloatArray(*arr->get(i), &p, width, lo, hi);
           if (!e.empty()) return fmt::format("point {}: {}", i, e);
           if (ascending && !pts.empty() && !(p[0] > pts.back()[0]))
             return fmt::format("point {}: {} does not follow {} (the points must be in increasing order)", i, p[0],
                                pts.back()[0]);
           pts.push_back(p);
         }
         *field = std::move(pts);
         return "";
       },
       [=] { return formatPoints(*field, width); }});
}

void ConfigSchema::choices(const std::string& key, std::vector<std::string>* field,
                           const std::vector<std::string>& def, const std::vector<std::string>& allowed,
                           const std::string& doc) {
  auto index = [allowed](const std::vector<std::string>& names) {
    std::vector<std::size_t> v;
    for (const auto& n : names) v.push_back(static_cast<std::size_t>(std::find(allowed.begin(), allowed.end(), n) -
                                                                     allowed.begin()));
    return v;
  };
  choicesIndex(
      key, allowed, index(def),
      [=](const std::vector<std::size_t>& v) {
        field->clear();
        for (const std::size_t i : v) field->push_back(allowed[i]);
      },
      [=] { return index(*field); }, doc);
}

void ConfigSchema::choicesIndex(const std::string& key, const std::vector<std::string>& allowed,
                                std::vector<std::size_t> def, std::function<void(const std::vector<std::size_t>&)> set,
                                std::function<std::vector<std::size_t>()> get, const std::string& doc) {
  PP5_CHECK(!def.empty());
  for (const std::size_t i : def) PP5_CHECK_LT(i, allowed.size());
  std::string list;
  for (const auto& c : allowed) list += (list.empty() ? "" : ", ") + c;
  auto names = [allowed](const std::vector<std::size_t>& v) {
    std::vector<std::string> out;
    for (const std::size_t i : v) out.push_back(i < allowed.size() ? allowed[i] : std::string("?"));
    return out;
  };
  add({key, "list of strings", formatStrings(names(def)), "each one of: " + list, doc, [=] { set(def); },
       [=](const toml::node& n) -> std::string {
         const auto* arr = n.as_array();
         if (!arr || arr->empty()) return "must be a non-empty array of strings";
         std::vector<std::size_t> v;
         for (std::size_t i = 0; i < arr->size(); ++i) {
           const auto* str = arr->get(i)->as_string();
           if (!str) return fmt::format("element {} must be a string", i);
           const std::string x = str->get();
           const auto it = std::find(allowed.begin(), allowed.end(), x);
           if (it == allowed.end()) return fmt::format("element {} = \"{}\" is not one of: {}", i, x, list);
           const auto k = static_cast<std::size_t>(it - allowed.begin());
           if (std::find(v.begin(), v.end(), k) != v.end()) return fmt::format("\"{}\" is listed twice", x);
           v.push_back(k);
         }
         set(v);
         return "";
       },
       [=] { return formatStrings(names(get())); }});
}

void ConfigSchema::option(const std::string& key, std::vector<std::string>* field, const std::vector<std::string>& def,
                          const std::string& doc) {
  add({key, "list of strings", formatStrings(def), "", doc, [=] { *field = def; },
       [=](const toml::node& n) -> std::string {
         const auto* arr = n.as_array();
         if (!arr) return "must be an array of strings";
         std::vector<std::string> v;
         for (std::size_t i = 0; i < arr->size(); ++i) {
           const auto* str = arr->get(i)->as_string();
           if (!str) return fmt::format("element {} must be a string", i);
           v.push_back(str->get());
         }
         *field = std::move(v);
         return "";
       },
       [=] { return formatStrings(*field); }});
}

void ConfigSchema::option(const std::string& key, glm::ivec2* field, glm::ivec2 def, int lo, int hi,
                          const std::string& doc) {
  add({key, "[int, int]", formatArray(&def[0], 2, fmtI), fmt::format("each {} .. {}", lo, hi), doc,
       [=] { *field = def; }, [=](const toml::node& n) { return readIntArray(n, field, 2, lo, hi); },
       [=] { return formatArray(&(*field)[0], 2, fmtI); }});
}

void ConfigSchema::applyDefaults() const {
  for (const auto& e : entries_) e.reset();
  assigned_.clear();
}

namespace {

struct Loader {
  const std::vector<ConfigSchema::Entry>& entries;
  const std::string& source;
  std::set<std::string>& assigned;

  bool isTablePrefix(const std::string& path) const {
    const std::string p = path + ".";
    return std::any_of(entries.begin(), entries.end(), [&](const auto& e) { return e.key.rfind(p, 0) == 0; });
  }
  const ConfigSchema::Entry* find(const std::string& key) const {
    for (const auto& e : entries)
      if (e.key == key) return &e;
    return nullptr;
  }
  long lineOf(const toml::node& n) const { return static_cast<long>(n.source().begin.line); }

  void walk(const toml::table& t, const std::string& prefix) const {
    for (const auto& [k, node] : t) {
      const std::string key = prefix.empty() ? std::string(k.str()) : prefix + "." + std::string(k.str());
      if (const auto* e = find(key)) {
        const std::string why = e->assign(node);
        if (!why.empty()) inputErrorAt(source, lineOf(node), "key '{}' {}", key, why);
        assigned.insert(key);
        continue;
      }
      if (const auto* sub = node.as_table(); sub && isTablePrefix(key)) {
        walk(*sub, key);
        continue;
      }
      inputErrorAt(source, lineOf(node), "unknown key '{}' (see docs/configuration.md for every option)", key);
    }
  }
};

}  // namespace

void ConfigSchema::loadString(const std::string& text, const std::string& sourceName) const {
  toml::table tbl;
  try {
    tbl = toml::parse(text, sourceName);
  } catch (const toml::parse_error& err) {
    inputErrorAt(sourceName, static_cast<long>(err.source().begin.line), "{}", err.description());
  }
  Loader{entries_, sourceName, assigned_}.walk(tbl, "");
}

void ConfigSchema::loadFile(const std::string& path) const {
  io::checkInputFile(path);
  toml::table tbl;
  try {
    tbl = toml::parse_file(path);
  } catch (const toml::parse_error& err) {
    // A missing file also lands here, at line 0.
    if (err.source().begin.line == 0) inputError(path, "{}", err.description());
    inputErrorAt(path, static_cast<long>(err.source().begin.line), "{}", err.description());
  }
  Loader{entries_, path, assigned_}.walk(tbl, "");
}

namespace {
// Whether `s` is well-formed UTF-8 (no overlong forms, surrogates or values
// past U+10FFFF).
bool isUtf8(std::string_view s) {
  std::size_t i = 0;
  while (i < s.size()) {
    const auto c = static_cast<unsigned char>(s[i]);
    const int n = c < 0x80 ? 0 : (c >> 5) == 0x6 ? 1 : (c >> 4) == 0xE ? 2 : (c >> 3) == 0x1E ? 3 : -1;
    if (n < 0 || s.size() - i <= static_cast<std::size_t>(n)) return false;  // (n = 0: never)
    std::uint32_t cp = n == 0 ? c : c & (0x3F >> n);
    for (int k = 1; k <= n; ++k) {
      const auto d = static_cast<unsigned char>(s[i + static_cast<std::size_t>(k)]);
      if ((d >> 6) != 0x2) return false;
      cp = (cp << 6) | (d & 0x3F);
    }
    static constexpr std::uint32_t kMin[4] = {0, 0x80, 0x800, 0x10000};
    if (cp < kMin[n] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return false;
    i += static_cast<std::size_t>(n) + 1;
  }
  return true;
}
}  // namespace

void ConfigSchema::set(const std::string& assignment) const {
  // TOML is UTF-8: other bytes would be re-encoded or dropped (a folder name
  // in Latin-1 became another folder).
  if (!isUtf8(assignment))
    throw InputError(fmt::format("--set '{}': holds bytes that are not UTF-8 (settings are UTF-8 text)",
                                 assignment.substr(0, assignment.find('='))));
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    throw InputError(fmt::format("--set '{}': expected key=value", assignment));
  auto trim = [](std::string s) {
    const auto b = s.find_first_not_of(" \t");
    const auto e = s.find_last_not_of(" \t");
    return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
  };
  const std::string key = trim(assignment.substr(0, eq));
  const std::string value = trim(assignment.substr(eq + 1));
  const std::string source = "--set " + key;
  // A bare word (sim.phantom=forearm) is taken as a string when it is not valid TOML.
  try {
    auto probe = toml::parse(key + " = " + value, source);
    (void)probe;
  } catch (const toml::parse_error&) {
    loadString(key + " = " + quote(value), source);
    return;
  }
  loadString(key + " = " + value, source);
}

std::string ConfigSchema::markdown() const {
  std::ostringstream os;
  auto sectionOf = [&](const std::string& key) {
    std::string best;
    for (const auto& s : sections_)
      if (key.rfind(s.name + ".", 0) == 0 && s.name.size() > best.size()) best = s.name;
    return best;
  };
  for (const auto& s : sections_) {
    os << "## [" << s.name << "]\n\n" << s.doc << "\n\n";
    os << "| key | type | default | range | meaning |\n|---|---|---|---|---|\n";
    for (const auto& e : entries_) {
      if (sectionOf(e.key) != s.name) continue;
      os << "| `" << e.key << "` | " << e.type << " | `" << e.def << "` | " << e.range << " | " << e.doc << " |\n";
    }
    os << "\n";
  }
  for (const auto& e : entries_)
    PP5_CHECK(!sectionOf(e.key).empty());  // every option belongs to a documented section
  return os.str();
}

std::string ConfigSchema::toToml() const {
  // Group by table in registration order so the file reads like the docs.
  std::vector<std::string> tables;
  std::map<std::string, std::vector<const Entry*>> byTable;
  for (const auto& e : entries_) {
    const auto dot = e.key.rfind('.');
    const std::string table = dot == std::string::npos ? "" : e.key.substr(0, dot);
    if (!byTable.count(table)) tables.push_back(table);
    byTable[table].push_back(&e);
  }
  std::ostringstream os;
  os << "# pp5echo settings as used (defaults included)\n";
  for (const auto& t : tables) {
    if (!t.empty()) os << "\n[" << t << "]\n";
    for (const auto* e : byTable[t]) os << e->key.substr(t.empty() ? 0 : t.size() + 1) << " = " << e->current() << "\n";
  }
  return os.str();
}

}  // namespace pp5
