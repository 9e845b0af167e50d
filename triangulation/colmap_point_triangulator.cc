#include "triangulation/colmap_point_triangulator.h"

#include <cstdlib>
#include <stdexcept>
#include <vector>

#include "util/check.h"
#include "util/subprocess.h"

namespace hscloc {

void ColmapPointTriangulatorOptions::Check() const {
  THROW_CHECK_MSG(!colmap_executable.empty(), "colmap_executable must not be empty");
}

std::filesystem::path FindColmap(const ColmapPointTriangulatorOptions& options) {
  options.Check();
  const auto colmap = FindExecutable(options.colmap_executable);
  if (!colmap) {
    ThrowInvalidArgument(
        "the COLMAP executable '{}' was not found{}: install COLMAP 3.8 (apt-get install colmap) "
        "or name it with --colmap PATH",
        options.colmap_executable,
        options.colmap_executable.find('/') == std::string::npos ? " on PATH" : "");
  }
  return *colmap;
}

void RunColmapPointTriangulator(const ColmapPointTriangulatorPaths& paths,
                                const ColmapPointTriangulatorOptions& options) {
  const std::filesystem::path colmap = FindColmap(options);
  std::filesystem::create_directories(paths.output_model);
  // COLMAP links Qt, which needs a display unless told to draw nowhere.
  setenv("QT_QPA_PLATFORM", "offscreen", /*overwrite=*/0);
  const std::vector<std::string> arguments = {colmap.string(),
                                              "point_triangulator",
                                              "--database_path",
                                              paths.database.string(),
                                              "--image_path",
                                              paths.image_dir.string(),
                                              "--input_path",
                                              paths.input_model.string(),
                                              "--output_path",
                                              paths.output_model.string(),
                                              "--Mapper.ba_refine_focal_length",
                                              "0",
                                              "--Mapper.ba_refine_principal_point",
                                              "0",
                                              "--Mapper.ba_refine_extra_params",
                                              "0"};
  const int status = RunProcess(arguments, paths.log);
  if (status != 0) {
    throw std::runtime_error(
        fmt::format("{} point_triangulator failed (exit status {}); its log "
                    "is {}, ending:\n{}",
                    colmap.string(), status, paths.log.string(), LastLines(paths.log, 15)));
  }
}

}  // namespace hscloc
