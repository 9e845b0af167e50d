// Test support shared by every folder's tests: a temporary directory per test and the location of
// the real data sets and the COLMAP binary.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <optional>
#include <string>

namespace hscloc::testing {

// A fresh directory removed with everything in it when the object goes out of scope.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// The real data directory (HSCLOC_DATA_DIR, set by ctest from the CMake cache variable), or
// nullopt where `subdirectory` of it does not exist.
std::optional<std::filesystem::path> RealDataDir(const std::string& subdirectory);

// The COLMAP executable (HSCLOC_COLMAP, set by ctest), or nullopt.
std::optional<std::string> ColmapExecutable();

// The message of the std::invalid_argument that `body` throws; records a test failure (and returns
// "") when it throws none.
std::string InvalidArgumentMessage(const std::function<void()>& body);

// Runs a shell command, returns its exit status; its output goes to `log_path` when given.
int RunCommand(const std::string& command, const std::string& log_path = "");

}  // namespace hscloc::testing

// Binds `variable` to the real data set `subdirectory`, or skips the test saying why.
#define HSCLOC_REQUIRE_REAL_DATA(variable, subdirectory)                          \
  const auto variable##_optional = ::hscloc::testing::RealDataDir(subdirectory);  \
  if (!variable##_optional) {                                                     \
    GTEST_SKIP() << "real data set '" << (subdirectory)                           \
                 << "' not found (set the CMake cache variable HSCLOC_DATA_DIR)"; \
  }                                                                               \
  const std::filesystem::path variable = *variable##_optional

#define HSCLOC_REQUIRE_COLMAP(variable)                                         \
  const auto variable##_optional = ::hscloc::testing::ColmapExecutable();       \
  if (!variable##_optional) {                                                   \
    GTEST_SKIP() << "the colmap binary was not found (apt-get install colmap)"; \
  }                                                                             \
  const std::string variable = *variable##_optional
