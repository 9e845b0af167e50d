// COLMAP's point_triangulator run as a program: 3D points from the matches of a database and the
// fixed poses of a model (COLMAP 3.8, src/exe/sfm.cc), with the intrinsics held fixed as hloc's
// triangulation holds them.
#pragma once

#include <filesystem>
#include <string>

namespace hscloc {

struct ColmapPointTriangulatorOptions {
  // The colmap executable: a path, or a name looked up on PATH.
  std::string colmap_executable = "colmap";
  void Check() const;
};

struct ColmapPointTriangulatorPaths {
  std::filesystem::path database;      // keypoints and verified matches (two_view_geometries)
  std::filesystem::path image_dir;     // the photos, for the points' colours (may be empty)
  std::filesystem::path input_model;   // cameras and posed images; 2D points: the keypoints
  std::filesystem::path output_model;  // created when missing
  std::filesystem::path log;           // COLMAP's output, kept
};

// The executable options.colmap_executable names; throws std::invalid_argument when there is none
// (naming it and the option that sets it), so that a pipeline can fail before its long steps.
std::filesystem::path FindColmap(const ColmapPointTriangulatorOptions& options);

// Runs `colmap point_triangulator` with focal length, principal point and distortion fixed.
// Throws as FindColmap when the executable is not found, std::runtime_error when COLMAP fails (its
// exit status, the log's path and last lines).
void RunColmapPointTriangulator(const ColmapPointTriangulatorPaths& paths,
                                const ColmapPointTriangulatorOptions& options = {});

}  // namespace hscloc
