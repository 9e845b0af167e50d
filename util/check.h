// Checks that throw instead of aborting, so a bad input becomes an error reply or a clean non-zero
// exit, never a crash. Every failure names the source location and, where given, the offending
// file, field or record.
#pragma once

#include <fmt/format.h>
#include <fmt/ostream.h>

#include <stdexcept>
#include <string>

namespace hscloc {

namespace internal {

[[noreturn]] void ThrowCheckFailure(const char* file, int line, const std::string& what);

template <typename A, typename B>
std::string FormatComparison(const char* expression, const A& a, const B& b) {
  return fmt::format("{} ({} vs. {})", expression, a, b);
}

}  // namespace internal

// Throws std::invalid_argument with the message formatted by fmt.
template <typename... Args>
[[noreturn]] void ThrowInvalidArgument(fmt::format_string<Args...> format, Args&&... args) {
  throw std::invalid_argument(fmt::format(format, std::forward<Args>(args)...));
}

}  // namespace hscloc

#define HSCLOC_INTERNAL_FILE_NAME \
  (__builtin_strrchr(__FILE__, '/') ? __builtin_strrchr(__FILE__, '/') + 1 : __FILE__)

// THROW_CHECK(cond): throws std::invalid_argument "file.cc:42: Check failed: cond".
#define THROW_CHECK(condition)                                                   \
  do {                                                                           \
    if (!(condition)) {                                                          \
      ::hscloc::internal::ThrowCheckFailure(HSCLOC_INTERNAL_FILE_NAME, __LINE__, \
                                            "Check failed: " #condition);        \
    }                                                                            \
  } while (false)

// THROW_CHECK_MSG(cond, "format {}", args...): as THROW_CHECK, followed by the formatted message.
#define THROW_CHECK_MSG(condition, ...)                                                \
  do {                                                                                 \
    if (!(condition)) {                                                                \
      ::hscloc::internal::ThrowCheckFailure(                                           \
          HSCLOC_INTERNAL_FILE_NAME, __LINE__,                                         \
          std::string("Check failed: " #condition ": ") + ::fmt::format(__VA_ARGS__)); \
    }                                                                                  \
  } while (false)

#define HSCLOC_INTERNAL_CHECK_OP(a, b, op)                                            \
  do {                                                                                \
    const auto& hscloc_check_a = (a);                                                 \
    const auto& hscloc_check_b = (b);                                                 \
    if (!(hscloc_check_a op hscloc_check_b)) {                                        \
      ::hscloc::internal::ThrowCheckFailure(                                          \
          HSCLOC_INTERNAL_FILE_NAME, __LINE__,                                        \
          "Check failed: " + ::hscloc::internal::FormatComparison(                    \
                                 #a " " #op " " #b, hscloc_check_a, hscloc_check_b)); \
    }                                                                                 \
  } while (false)

#define THROW_CHECK_EQ(a, b) HSCLOC_INTERNAL_CHECK_OP(a, b, ==)
#define THROW_CHECK_NE(a, b) HSCLOC_INTERNAL_CHECK_OP(a, b, !=)
#define THROW_CHECK_LT(a, b) HSCLOC_INTERNAL_CHECK_OP(a, b, <)
#define THROW_CHECK_LE(a, b) HSCLOC_INTERNAL_CHECK_OP(a, b, <=)
#define THROW_CHECK_GT(a, b) HSCLOC_INTERNAL_CHECK_OP(a, b, >)
#define THROW_CHECK_GE(a, b) HSCLOC_INTERNAL_CHECK_OP(a, b, >=)
