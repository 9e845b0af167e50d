// Geometric verification of matches between two images whose poses are known: each match must lie
// near its epipolar lines, as hloc's triangulation verifies matches against a reference model
// (hloc/triangulation.py, geometric_verification) instead of estimating a relative pose.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "scene/colmap_database_writer.h"
#include "scene/features.h"

namespace hscloc {

struct EpipolarVerificationOptions {
  // Largest distance, in pixels of each image, of a keypoint from the epipolar line of its match
  // (hloc's max_error: 4 px).
  double max_epipolar_error_px = 4.0;
  // A pair with fewer inliers is dropped (COLMAP's two-view geometry minimum, min_num_inliers).
  int min_num_inliers = 15;
  void Check() const;
};

// The keypoints of a posed image, undistorted once for all the pairs it takes part in.
struct PosedKeypoints {
  Rigid3d cam_from_world;
  // The camera's mean focal length: a distance in normalized coordinates times this is pixels.
  double focal_length_px = 0;
  // Undistorted normalized coordinates (x/z, y/z), one keypoint per row; NaN where the camera's
  // distortion has no inverse.
  Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> normalized;
};

// Keypoints in pixels (COLMAP's convention) through `camera`'s model to normalized coordinates.
PosedKeypoints UndistortKeypoints(const Camera& camera, const Rigid3d& cam_from_world,
                                  const KeypointMatrix& keypoints);

// Per match, the larger of its two point-to-epipolar-line distances in pixels: with
// E = [t]x R of cam2_from_cam1, the line of x1 in image 2 is E x1 and that of x2 in image 1 is
// E^T x2, the distance of x2 from E x1 is |x2^T E x1| / ||(E x1)_xy||, times image 2's focal
// length (and symmetrically for x1). Infinity for a keypoint without undistortion or a degenerate
// line (a pair whose centres coincide has no epipolar geometry).
std::vector<double> EpipolarErrorsPx(const PosedKeypoints& image1, const PosedKeypoints& image2,
                                     const std::vector<FeatureMatch>& matches);

struct VerifiedMatches {
  std::vector<FeatureMatch> inliers;  // in the order of the matches given
  // Whether the pair keeps its inliers: at least min_num_inliers of them.
  bool accepted = false;
};

// The matches within max_epipolar_error_px in both images.
VerifiedMatches VerifyWithKnownPoses(const PosedKeypoints& image1, const PosedKeypoints& image2,
                                     const std::vector<FeatureMatch>& matches,
                                     const EpipolarVerificationOptions& options = {});

}  // namespace hscloc
