// Test support shared by every folder's tests: a temporary directory per test and the location of
// the real data sets and the COLMAP binary.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "util/random.h"

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

// `subdirectory` of the real data directory (HSCLOC_DATA_DIR, set by ctest from the CMake cache
// variable), or else of the project's own data/ (the sets that ship with it); nullopt where
// neither holds it.
std::optional<std::filesystem::path> RealDataDir(const std::string& subdirectory);

// The trained `small` synthetic city that the test suite's fixture builds (tests/CMakeLists.txt):
// `city/` (COLMAP model, features.h5, queries) and `map/` (the bundle with its network). From
// HSCLOC_TRAINED_SMALL_CITY or the build's default; nullopt until the fixture has run.
std::optional<std::filesystem::path> TrainedSmallCityDir();

// `count` normal values of standard deviation `stddev`, as floats (kernel inputs).
inline std::vector<float> NormalFloats(int64_t count, Random& random, double stddev = 1) {
  std::vector<float> values(count);
  for (float& value : values) value = static_cast<float>(stddev * random.Normal());
  return values;
}

// The COLMAP executable (HSCLOC_COLMAP, set by ctest), or nullopt.
std::optional<std::string> ColmapExecutable();

// Prometheus's promtool (HSCLOC_PROMTOOL), or nullopt.
std::optional<std::string> PromtoolExecutable();

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

#define HSCLOC_REQUIRE_TRAINED_SMALL_CITY(variable)                                          \
  const auto variable##_optional = ::hscloc::testing::TrainedSmallCityDir();                 \
  if (!variable##_optional) {                                                                \
    GTEST_SKIP() << "the trained small city is missing: run the tests through ctest, whose " \
                    "fixture.trained_small_city builds it";                                  \
  }                                                                                          \
  const std::filesystem::path variable = *variable##_optional

#define HSCLOC_REQUIRE_COLMAP(variable)                                         \
  const auto variable##_optional = ::hscloc::testing::ColmapExecutable();       \
  if (!variable##_optional) {                                                   \
    GTEST_SKIP() << "the colmap binary was not found (apt-get install colmap)"; \
  }                                                                             \
  const std::string variable = *variable##_optional

#define HSCLOC_REQUIRE_PROMTOOL(variable)                                   \
  const auto variable##_optional = ::hscloc::testing::PromtoolExecutable(); \
  if (!variable##_optional) {                                               \
    GTEST_SKIP() << "promtool was not found (apt-get install prometheus)";  \
  }                                                                         \
  const std::string variable = *variable##_optional
