// Writing a COLMAP database.db for COLMAP's own tools (point_triangulator, image_registrator):
// the schema COLMAP 3.8 creates (src/base/database.cc), cameras and images with the ids the caller
// gives, keypoints, matches and two-view geometries. Descriptors are not written: COLMAP's
// triangulation and registration read only keypoints and verified matches.
//
// Blob layouts (COLMAP's, row-major, little-endian):
//   cameras.params            float64[model's count]
//   keypoints                 float32 N x 2, pixels in COLMAP's convention (the centre of the
//                             top-left pixel at (0.5, 0.5)), as hscloc holds keypoints
//   matches, two_view_geometries.data   uint32 M x 2 (keypoint rows of image_id1, image_id2)
//   two_view_geometries F, E, H float64 3 x 3; qvec float64[4] (w, x, y, z); tvec float64[3]
// A pair is stored once, under PairId(image_id1, image_id2) with image_id1 < image_id2; the writer
// swaps the columns of a pair given the other way round.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "scene/features.h"
#include "util/types.h"

namespace hscloc {

// Image ids must stay below this (COLMAP's images.image_id check and its pair id encoding).
inline constexpr int64_t kColmapMaxNumImages = 2147483647;

// COLMAP's pair id: image_id1 * 2147483647 + image_id2 with the smaller id first.
int64_t ColmapPairId(image_t image_id1, image_t image_id2);

// Keypoint rows of two images that show the same scene point.
struct FeatureMatch {
  point2D_t point2D_idx1 = kInvalidPoint2DIdx;
  point2D_t point2D_idx2 = kInvalidPoint2DIdx;
  bool operator==(const FeatureMatch& other) const {
    return point2D_idx1 == other.point2D_idx1 && point2D_idx2 == other.point2D_idx2;
  }
};

// COLMAP's TwoViewGeometry::ConfigurationType values that hscloc writes.
enum class TwoViewConfiguration : int { kCalibrated = 2 };

// Writes one new database in a single transaction: nothing is visible to readers until Close().
// Every method throws std::invalid_argument naming the file and the record that failed (a
// duplicate id or pair, an image whose camera was not written, an id out of COLMAP's range).
class ColmapDatabaseWriter {
 public:
  // Creates `path` with COLMAP 3.8's tables; throws when the file exists (COLMAP would append to
  // it) or cannot be created.
  explicit ColmapDatabaseWriter(const std::filesystem::path& path);
  // Rolls back what was not closed: an interrupted writer leaves an empty database.
  ~ColmapDatabaseWriter();
  ColmapDatabaseWriter(const ColmapDatabaseWriter&) = delete;
  ColmapDatabaseWriter& operator=(const ColmapDatabaseWriter&) = delete;

  // prior_focal_length is set: the camera is known, as hloc marks a reference model's cameras.
  void WriteCamera(const Camera& camera);
  void WriteImage(image_t image_id, const std::string& name, camera_t camera_id);
  void WriteKeypoints(image_t image_id, const KeypointMatrix& keypoints);
  // Raw (putative) matches of a pair.
  void WriteMatches(image_t image_id1, image_t image_id2, const std::vector<FeatureMatch>& matches);
  // Verified matches of a pair with their relative pose: E = [t]x R of cam2_from_cam1 (for the
  // pair in stored order); F and H are left zero, as they are not estimated.
  void WriteTwoViewGeometry(image_t image_id1, image_t image_id2,
                            const std::vector<FeatureMatch>& inlier_matches,
                            const Rigid3d& cam2_from_cam1,
                            TwoViewConfiguration configuration = TwoViewConfiguration::kCalibrated);
  // Commits; throws when the commit fails.
  void Close();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hscloc
