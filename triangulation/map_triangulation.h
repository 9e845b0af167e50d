// A map for a new kind of local features from the known poses of an existing COLMAP model, as
// hloc's triangulation.py makes one: the model's co-visible image pairs are matched (mutual
// nearest neighbours, ratio test), verified against the known poses (epipolar distance), written
// into a COLMAP database with the model's camera and image ids, and COLMAP's point_triangulator
// triangulates them with poses and intrinsics fixed. The result's 2D points are the features'
// keypoints, in their order, so that build-map can join it with the same feature file.
#pragma once

#include <cstdint>
#include <filesystem>

#include "triangulation/colmap_point_triangulator.h"
#include "triangulation/descriptor_matching.h"
#include "triangulation/epipolar_verification.h"
#include "triangulation/pair_selection.h"

namespace hscloc {

struct MapTriangulationOptions {
  PairSelectionOptions pairs;
  DescriptorMatchingOptions matching;
  EpipolarVerificationOptions verification;
  ColmapPointTriangulatorOptions colmap;
  // Threads matching pairs (<= 0: all cores).
  int num_threads = 0;
  // The images whose descriptors are held at once while matching (2048 XFeat keypoints: 0.5 MiB
  // each; 4096 SuperPoint ones: 4 MiB). Keypoints and their undistorted coordinates of every
  // image stay in memory (48 KiB per 2048 keypoints).
  int max_images_in_memory = 512;
  // Progress bars on stderr for reading features and matching.
  bool show_progress = true;
  void Check() const;
};

struct MapTriangulationInputs {
  std::filesystem::path model_dir;  // COLMAP model (bin or txt) with the poses to keep
  std::filesystem::path features;   // hloc .h5 or COLMAP database.db with every model image
  std::filesystem::path image_dir;  // photos, for the points' colours; empty: no colours
};

struct MapTriangulationSummary {
  int64_t num_images = 0;            // in the input model
  int64_t num_pairs = 0;             // matched
  int64_t num_verified_pairs = 0;    // with at least min_num_inliers epipolar inliers
  int64_t num_matches = 0;           // mutual nearest neighbours passing the ratio test, all pairs
  int64_t num_verified_matches = 0;  // inliers of the verified pairs
  int64_t num_matching_chunks = 0;   // rounds of matching, each within max_images_in_memory
  // Images whose descriptors were read again for matching (none when every image's fit in
  // max_images_in_memory: they are kept from the first read).
  int64_t num_descriptor_reads = 0;
  // Read back from the triangulated model.
  int64_t num_registered_images = 0;
  int64_t num_points3D = 0;
  int64_t num_observations = 0;
  double mean_track_length = 0;
  double mean_reprojection_error_px = 0;  // mean of the points' errors, as COLMAP reports it
  double seconds_matching = 0;            // features read, matched and verified
  double seconds_triangulation = 0;       // COLMAP
  double seconds_total = 0;
};

// The files TriangulateMap leaves in its output directory besides the model.
struct MapTriangulationFiles {
  static constexpr const char* kWorkDir = "triangulation";
  static constexpr const char* kDatabase = "triangulation/database.db";
  static constexpr const char* kInputModel = "triangulation/input_model";
  static constexpr const char* kColmapLog = "triangulation/point_triangulator.log";
  static constexpr const char* kNoImages = "triangulation/no_images";  // without --images
};

// Writes the triangulated binary model into `out_dir` (created; a model and the work files of an
// earlier run there are replaced) and, under out_dir/triangulation/, the database, the input
// model and COLMAP's log. Throws std::invalid_argument naming the input at fault: a model that
// cannot be read, a model image without features, features of another image size (a keypoint
// outside the camera), descriptor dimensions that differ, no colmap executable;
// std::runtime_error when COLMAP fails.
MapTriangulationSummary TriangulateMap(const MapTriangulationInputs& inputs,
                                       const MapTriangulationOptions& options,
                                       const std::filesystem::path& out_dir);

}  // namespace hscloc
