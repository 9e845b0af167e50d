// The options of hscloc-bench, shared by its steps.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace hscloc::bench {

struct BenchOptions {
  bool quick = false;
  bool from_json = false;       // only rewrite the report from the JSON file's numbers
  std::string scale_only;       // only measure this preset's scale row, into the existing JSON
  bool real_sets_only = false;  // only measure the real sets' peers rows, into the existing JSON
  double train_minutes = 0;     // training budget of --scale-only (0: the full run's)
  // The real sets' training budget in minutes (0: `hscloc train`'s own for the map); a row
  // measured with one is named after it, beside the default's.
  double real_train_minutes = 0;
  int seeds = 5;                      // the real sets' training seeds, 1 .. seeds
  std::string appearance = "random";  // of --scale-only's city: random or real
  std::filesystem::path work = "bench-work";
  std::filesystem::path data = HSCLOC_DEFAULT_DATA_DIR;
  // The sets that ship with the project (kitti-07), read where `data` lacks them.
  std::filesystem::path project_data = HSCLOC_PROJECT_DATA_DIR;
  // The real sets measured (by name, e.g. lund); empty: all of them.
  std::vector<std::string> real_sets;
  std::filesystem::path report = "docs/performance.md";
  std::filesystem::path json_path;  // default: the report's path with .json
  std::string hscloc = HSCLOC_TOOL_PATH;
  std::string colmap = "colmap";
};

// The folder of a real set (or of the XFeat weights): under `data`, else under `project_data`.
inline std::filesystem::path RealDataPath(const BenchOptions& options,
                                          const std::filesystem::path& relative) {
  const std::filesystem::path shared = options.data / relative;
  return std::filesystem::exists(shared) ? shared : options.project_data / relative;
}

}  // namespace hscloc::bench
