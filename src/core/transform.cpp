#include "core/transform.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cctype>
#include <deque>
#include <map>
#include <system_error>

#include <fmt/format.h>

#include "core/error.hpp"

namespace pp5 {

Mat4 fromRowMajor(const std::array<double, 16>& v) {
  Mat4 m(0.0);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m[c][r] = v[static_cast<std::size_t>(r * 4 + c)];
  return m;
}

std::array<double, 16> toRowMajor(const Mat4& m) {
  std::array<double, 16> v{};
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) v[static_cast<std::size_t>(r * 4 + c)] = m[c][r];
  return v;
}

namespace {

bool isSpace(char ch) { return ch == ' ' || ch == '\t' || ch == '\n' || ch == '\r' || ch == '\f' || ch == '\v'; }

// A token as it appears in the text, shortened so that an error message stays one line.
std::string quoted(std::string_view tok) {
  constexpr std::size_t kMax = 40;
  if (tok.size() > kMax) return fmt::format("'{}...'", tok.substr(0, kMax));
  return fmt::format("'{}'", tok);
}

}  // namespace

std::optional<Mat4> parseRowMajor(const std::string& text, std::string* why) {
  std::array<double, 16> v{};
  std::size_t count = 0;
  std::size_t i = 0;
  const std::size_t n = text.size();
  while (i < n) {
    while (i < n && isSpace(text[i])) ++i;
    if (i >= n) break;
    std::size_t j = i;
    while (j < n && !isSpace(text[j])) ++j;
    const std::string_view tok(text.data() + i, j - i);
    // from_chars rejects a leading '+', which other writers do emit.
    std::string_view num = tok;
    if (num.size() > 1 && num.front() == '+' && num[1] != '-') num.remove_prefix(1);
    double x = 0.0;
    const auto [end, ec] = std::from_chars(num.data(), num.data() + num.size(), x);
    if (ec == std::errc::result_out_of_range) {
      if (why) *why = fmt::format("{} is out of range for a double", quoted(tok));
      return std::nullopt;
    }
    if (ec != std::errc() || end != num.data() + num.size()) {
      if (why) *why = fmt::format("{} is not a number", quoted(tok));
      return std::nullopt;
    }
    if (!std::isfinite(x)) {
      if (why) *why = fmt::format("{} is not a finite number", quoted(tok));
      return std::nullopt;
    }
    if (count < v.size()) v[count] = x;
    ++count;
    i = j;
  }
  if (count != 16) {
    if (why) *why = fmt::format("has {} number{}, expected 16", count, count == 1 ? "" : "s");
    return std::nullopt;
  }
  return fromRowMajor(v);
}

std::string formatRowMajor(const Mat4& m) {
  // fmt's "{}" for double is the shortest text that reads back to the same value.
  const auto v = toRowMajor(m);
  std::string s;
  for (std::size_t k = 0; k < v.size(); ++k) {
    if (k > 0) s += (k % 4 == 0) ? "  " : " ";
    s += fmt::format("{}", v[k]);
  }
  return s;
}

bool isFinite(const Mat4& m) {
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r)
      if (!std::isfinite(m[c][r])) return false;
  return true;
}

bool isRigid(const Mat4& m, double tol) {
  if (!isFinite(m)) return false;
  // Last row (0 0 0 1).
  if (std::abs(m[0][3]) > tol || std::abs(m[1][3]) > tol || std::abs(m[2][3]) > tol || std::abs(m[3][3] - 1.0) > tol)
    return false;
  const glm::dmat3 r(m);
  const glm::dmat3 rtr = glm::transpose(r) * r;
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k)
      if (std::abs(rtr[c][k] - (c == k ? 1.0 : 0.0)) > tol) return false;
  // A reflection is orthonormal too, but it is not a motion of a rigid body.
  return glm::determinant(r) > 0.0;
}

Mat4 affineInverse(const Mat4& m) {
  const bool affine = m[0][3] == 0.0 && m[1][3] == 0.0 && m[2][3] == 0.0 && m[3][3] == 1.0;
  if (!affine) return glm::inverse(m);  // not affine: no shortcut applies
  // [A t; 0 1]^-1 = [A^-1  -A^-1 t; 0 1]. A singular A gives non-finite entries,
  // which callers detect with isFinite().
  const glm::dmat3 a(m);
  const glm::dmat3 ai = isRigid(m, 1e-12) ? glm::transpose(a) : glm::inverse(a);
  const Vec3 t(m[3]);
  Mat4 out(ai);
  out[3] = Vec4(-(ai * t), 1.0);
  return out;
}

Mat4 translation(const Vec3& t) {
  Mat4 m(1.0);
  m[3] = Vec4(t, 1.0);
  return m;
}

Mat4 rotationAxisAngle(const Vec3& axis, double radians) {
  const double len = glm::length(axis);
  if (!(len > 0.0) || !std::isfinite(len)) return Mat4(1.0);  // no axis, no rotation
  const Vec3 u = axis / len;
  const double c = std::cos(radians);
  const double s = std::sin(radians);
  const double t = 1.0 - c;
  // Rodrigues' formula, written per element (row r, column k -> m[k][r]).
  Mat4 m(1.0);
  m[0][0] = c + u.x * u.x * t;
  m[1][0] = u.x * u.y * t - u.z * s;
  m[2][0] = u.x * u.z * t + u.y * s;
  m[0][1] = u.y * u.x * t + u.z * s;
  m[1][1] = c + u.y * u.y * t;
  m[2][1] = u.y * u.z * t - u.x * s;
  m[0][2] = u.z * u.x * t - u.y * s;
  m[1][2] = u.z * u.y * t + u.x * s;
  m[2][2] = c + u.z * u.z * t;
  return m;
}

Mat4 scaling(const Vec3& s) {
  Mat4 m(1.0);
  m[0][0] = s.x;
  m[1][1] = s.y;
  m[2][2] = s.z;
  return m;
}

// ---- TransformRepository ----

void TransformRepository::set(const std::string& from, const std::string& to, const Mat4& m, bool valid) {
  PP5_CHECK(!from.empty() && !to.empty());
  PP5_CHECK_NE(from, to);
  // One stored edge per pair of frames: a new BToA replaces an old AToB, so the
  // two directions can never disagree.
  for (auto& e : edges_) {
    if ((e.from == from && e.to == to) || (e.from == to && e.to == from)) {
      e.from = from;
      e.to = to;
      e.m = m;
      e.valid = valid;
      return;
    }
  }
  edges_.push_back({from, to, m, valid});
}

std::vector<std::string> TransformRepository::path(const std::string& from, const std::string& to) const {
  if (from == to) return {from};
  // Breadth-first search over frames; neighbours are visited in the order the
  // edges were added, so the chosen chain is deterministic.
  std::map<std::string, std::string> parent;  // frame -> frame it was reached from
  std::deque<std::string> queue;
  parent[from] = from;
  queue.push_back(from);
  bool found = false;
  while (!queue.empty() && !found) {
    const std::string cur = queue.front();
    queue.pop_front();
    for (const auto& e : edges_) {
      const std::string* next = nullptr;
      if (e.from == cur) next = &e.to;
      else if (e.to == cur) next = &e.from;
      if (!next || parent.count(*next)) continue;
      parent[*next] = cur;
      if (*next == to) {
        found = true;
        break;
      }
      queue.push_back(*next);
    }
  }
  if (!found) return {};
  std::vector<std::string> chain;
  for (std::string f = to; f != from; f = parent[f]) chain.push_back(f);
  chain.push_back(from);
  std::reverse(chain.begin(), chain.end());
  return chain;
}

std::optional<Mat4> TransformRepository::get(const std::string& from, const std::string& to) const {
  if (from == to) return Mat4(1.0);
  const auto chain = path(from, to);
  if (chain.empty()) return std::nullopt;
  Mat4 acc(1.0);  // maps `from` into chain[k]
  for (std::size_t k = 0; k + 1 < chain.size(); ++k) {
    const std::string& a = chain[k];
    const std::string& b = chain[k + 1];
    for (const auto& e : edges_) {
      if (e.from == a && e.to == b) {
        if (!e.valid) return std::nullopt;
        acc = e.m * acc;
        break;
      }
      if (e.from == b && e.to == a) {
        if (!e.valid) return std::nullopt;
        acc = affineInverse(e.m) * acc;
        break;
      }
    }
  }
  return acc;
}

std::vector<std::string> TransformRepository::frames() const {
  std::vector<std::string> out;
  auto add = [&out](const std::string& f) {
    if (std::find(out.begin(), out.end(), f) == out.end()) out.push_back(f);
  };
  for (const auto& e : edges_) {
    add(e.from);
    add(e.to);
  }
  return out;
}

// ---- names ----

// PLUS names a transform "<From>To<To>", with each frame name starting with an
// uppercase letter. "To" may also occur inside a frame name ("StylusTipToTool",
// "TorsoToReference"), so only a "To" followed by an uppercase letter counts.
// If several such positions remain, the split is ambiguous
// ("ImageToTorsoToReference" may be Image->TorsoToReference or
// ImageToTorso->Reference); PLUS refuses such names, and so do we (nullopt).
std::optional<std::pair<std::string, std::string>> splitTransformName(const std::string& name) {
  auto upper = [](char ch) { return std::isupper(static_cast<unsigned char>(ch)) != 0; };
  std::vector<std::size_t> candidates;  // every "To" followed by an uppercase letter
  for (std::size_t i = 0; i + 2 < name.size(); ++i)
    if (name[i] == 'T' && name[i + 1] == 'o' && upper(name[i + 2])) candidates.push_back(i);
  if (candidates.empty()) return std::nullopt;
  std::vector<std::size_t> good;  // ... with a non-empty From that starts with an uppercase letter
  for (std::size_t i : candidates)
    if (i > 0 && upper(name[0])) good.push_back(i);
  std::size_t pos = 0;
  if (good.size() == 1) {
    pos = good.front();
  } else if (good.empty() && candidates.size() == 1 && candidates.front() > 0) {
    pos = candidates.front();  // e.g. "probeToTracker": From is lowercase but unambiguous
  } else {
    return std::nullopt;  // ambiguous, or From would be empty
  }
  return std::make_pair(name.substr(0, pos), name.substr(pos + 2));
}

double largestDisplacement(const Mat4& a, const Mat4& b, std::span<const Vec3> points) {
  double d = 0.0;
  for (const Vec3& p : points) d = std::max(d, glm::length(transformPoint(a, p) - transformPoint(b, p)));
  return d;
}

}  // namespace pp5
