#include "localization/rival_matches.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "util/check.h"

namespace hscloc {
namespace {

// The match `score` ranks highest for each point (ties: the first), in keypoint order.
template <typename Score>
CandidateMatches BestKeypointPerPoint(const CandidateMatches& predictions, Score score) {
  // Matches grouped by point through one sort of (point, match) packed in an integer: a hash map
  // of the points took most of the visibility stage.
  std::vector<uint64_t> by_point(predictions.size());
  for (size_t i = 0; i < predictions.size(); ++i) {
    by_point[i] = uint64_t{predictions.point_indices[i]} << 32 | i;
  }
  std::sort(by_point.begin(), by_point.end());
  std::vector<size_t> kept;
  double kept_score = 0;
  for (size_t j = 0; j < by_point.size(); ++j) {
    const size_t match = by_point[j] & 0xffffffffu;
    const double match_score = score(match);
    if (j == 0 || by_point[j] >> 32 != by_point[j - 1] >> 32) {
      kept.push_back(match);
      kept_score = match_score;
    } else if (match_score > kept_score) {
      kept.back() = match;
      kept_score = match_score;
    }
  }
  std::sort(kept.begin(), kept.end(), [&](size_t a, size_t b) {
    return predictions.keypoints[a] != predictions.keypoints[b]
               ? predictions.keypoints[a] < predictions.keypoints[b]
               : a < b;
  });
  return SelectMatches(predictions, kept);
}

void CheckConfidences(const CandidateMatches& predictions) {
  THROW_CHECK_MSG(predictions.point_indices.size() == predictions.size() &&
                      predictions.confidences.size() == predictions.size(),
                  "{} keypoints, {} points and {} confidences: one each per match",
                  predictions.size(), predictions.point_indices.size(),
                  predictions.confidences.size());
}

}  // namespace

CandidateMatches MostConfidentKeypointPerPoint(const CandidateMatches& predictions) {
  CheckConfidences(predictions);
  return BestKeypointPerPoint(predictions, [&](size_t i) { return predictions.confidences[i]; });
}

CandidateMatches NearestKeypointPerPoint(const CandidateMatches& predictions,
                                         const KeypointMatrix& keypoints, const Camera& camera,
                                         const Rigid3d& cam_from_world,
                                         const std::vector<Eigen::Vector3d>& points) {
  CheckConfidences(predictions);
  // Rivals share their point: either it reprojects for all of them and nearer is better, or it
  // lies behind the camera (or beyond the camera model) for all of them and confidence decides.
  return BestKeypointPerPoint(predictions, [&](size_t i) -> double {
    const Eigen::Vector3d point_in_cam = cam_from_world * points.at(predictions.point_indices[i]);
    if (!(point_in_cam.z() > 0.0)) return predictions.confidences[i];
    const Eigen::Vector2d keypoint =
        keypoints.row(predictions.keypoints[i]).transpose().cast<double>();
    const double distance = (camera.ImgFromPointInCam(point_in_cam) - keypoint).norm();
    return std::isfinite(distance) ? -distance : predictions.confidences[i];
  });
}

}  // namespace hscloc
