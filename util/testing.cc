#include "util/testing.h"

#include <unistd.h>

#include <cstdlib>
#include <random>
#include <stdexcept>

namespace hscloc::testing {

TempDir::TempDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = info ? std::string(info->test_suite_name()) + "." + info->name() : "test";
  for (char& c : name) {
    if (c == '/') c = '_';
  }
  std::random_device random;
  path_ = std::filesystem::temp_directory_path() /
          ("hscloc_" + name + "_" + std::to_string(getpid()) + "_" + std::to_string(random()));
  std::filesystem::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ignored;
  std::filesystem::remove_all(path_, ignored);
}

namespace {

const char* EnvironmentOr(const char* name, const char* fallback) {
  const char* value = std::getenv(name);
  return value != nullptr ? value : fallback;
}

}  // namespace

std::optional<std::filesystem::path> RealDataDir(const std::string& subdirectory) {
  for (const char* root :
       {EnvironmentOr("HSCLOC_DATA_DIR", HSCLOC_DEFAULT_DATA_DIR), HSCLOC_PROJECT_DATA_DIR}) {
    if (*root == '\0') continue;
    const std::filesystem::path path = std::filesystem::path(root) / subdirectory;
    if (std::filesystem::is_directory(path)) return path;
  }
  return std::nullopt;
}

std::optional<std::filesystem::path> TrainedSmallCityDir() {
  const std::filesystem::path dir =
      EnvironmentOr("HSCLOC_TRAINED_SMALL_CITY", HSCLOC_DEFAULT_TRAINED_SMALL_CITY);
  if (dir.empty() || !std::filesystem::exists(dir / "map" / "network.pt")) return std::nullopt;
  return dir;
}

std::optional<std::string> ColmapExecutable() {
  const char* path = EnvironmentOr("HSCLOC_COLMAP", HSCLOC_DEFAULT_COLMAP);
  if (*path == '\0' || access(path, X_OK) != 0) return std::nullopt;
  return std::string(path);
}

std::optional<std::string> PromtoolExecutable() {
  const char* path = EnvironmentOr("HSCLOC_PROMTOOL", HSCLOC_DEFAULT_PROMTOOL);
  if (*path == '\0' || access(path, X_OK) != 0) return std::nullopt;
  return std::string(path);
}

std::string InvalidArgumentMessage(const std::function<void()>& body) {
  try {
    body();
  } catch (const std::invalid_argument& error) {
    return error.what();
  }
  ADD_FAILURE() << "expected a std::invalid_argument";
  return "";
}

int RunCommand(const std::string& command, const std::string& log_path) {
  // COLMAP links Qt, which needs a display unless told to draw nowhere.
  setenv("QT_QPA_PLATFORM", "offscreen", /*overwrite=*/0);
  const std::string full = log_path.empty() ? command : command + " > '" + log_path + "' 2>&1";
  const int status = std::system(full.c_str());
  if (status == -1) throw std::runtime_error("could not run: " + command);
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128;
}

}  // namespace hscloc::testing
