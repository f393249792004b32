#pragma once
// Error channels (see docs/architecture.md):
//  - InputError: bad input or configuration. One clear sentence naming the file
//    (and line or frame where known). The app prints it and exits non-zero.
//  - DeviceError: a live device or connection failed at run time (the board
//    unplugged for good, a server that cannot be reached). One sentence naming
//    the device; the app prints it and exits non-zero.
//  - PP5_CHECK*: internal invariants. On failure they print both values and the
//    source location, then throw InvariantError (never a silent abort).
#include <sstream>
#include <stdexcept>
#include <string>

#include <fmt/format.h>

namespace pp5 {

class InputError : public std::runtime_error {
public:
  using std::runtime_error::runtime_error;
};

class DeviceError : public std::runtime_error {
public:
  using std::runtime_error::runtime_error;
};

class InvariantError : public std::logic_error {
public:
  using std::logic_error::logic_error;
};

// Builds "FILE: message" or "FILE:LINE: message"; all input errors use this shape.
template <typename... Args>
[[noreturn]] void inputError(const std::string& file, fmt::format_string<Args...> f, Args&&... args) {
  throw InputError(file + ": " + fmt::format(f, std::forward<Args>(args)...));
}
template <typename... Args>
[[noreturn]] void inputErrorAt(const std::string& file, long line, fmt::format_string<Args...> f,
                               Args&&... args) {
  throw InputError(file + ":" + std::to_string(line) + ": " + fmt::format(f, std::forward<Args>(args)...));
}

namespace detail {
template <typename A, typename B>
[[noreturn]] void checkFailed(const char* expr, const A& a, const B& b, const char* file, int line) {
  std::ostringstream os;
  os << file << ":" << line << ": invariant failed: " << expr << " (lhs = " << a << ", rhs = " << b << ")";
  throw InvariantError(os.str());
}
}  // namespace detail

}  // namespace pp5

#define PP5_CHECK_OP(a, op, b)                                                       \
  do {                                                                               \
    const auto& pp5_a_ = (a);                                                        \
    const auto& pp5_b_ = (b);                                                        \
    if (!(pp5_a_ op pp5_b_))                                                         \
      ::pp5::detail::checkFailed(#a " " #op " " #b, pp5_a_, pp5_b_, __FILE__, __LINE__); \
  } while (0)
#define PP5_CHECK_EQ(a, b) PP5_CHECK_OP(a, ==, b)
#define PP5_CHECK_NE(a, b) PP5_CHECK_OP(a, !=, b)
#define PP5_CHECK_LT(a, b) PP5_CHECK_OP(a, <, b)
#define PP5_CHECK_LE(a, b) PP5_CHECK_OP(a, <=, b)
#define PP5_CHECK_GT(a, b) PP5_CHECK_OP(a, >, b)
#define PP5_CHECK_GE(a, b) PP5_CHECK_OP(a, >=, b)
#define PP5_CHECK(cond)                                                              \
  do {                                                                               \
    if (!(cond))                                                                     \
      throw ::pp5::InvariantError(std::string(__FILE__) + ":" + std::to_string(__LINE__) + \
                                  ": invariant failed: " #cond);                     \
  } while (0)
