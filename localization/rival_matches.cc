#include "localization/rival_matches.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "util/check.h"
#include "util/radix_sort.h"

namespace hscloc {
namespace {

// The match `score` ranks highest for each point (ties: the first), in keypoint order.
template <typename Score>
CandidateMatches BestKeypointPerPoint(const CandidateMatches& predictions, Score score) {
  // Matches grouped by point through one linear-time sort (a hash map of the points took most of
  // the visibility stage, a comparison sort most of what was left); equal points keep match order.
  std::vector<std::pair<int64_t, int64_t>> by_point(predictions.size());
  for (size_t i = 0; i < predictions.size(); ++i) {
    THROW_CHECK_MSG(predictions.keypoints[i] >= 0, "match {} has keypoint {}, negative", i,
                    predictions.keypoints[i]);
    by_point[i] = {predictions.point_indices[i], static_cast<int64_t>(i)};
  }
  std::vector<std::pair<int64_t, int64_t>> scratch;
  StableSortByKey(by_point, scratch);
  // The kept matches, each as (keypoint, match) packed, to be put in that order.
  std::vector<std::pair<int64_t, int64_t>> kept;
  double kept_score = 0;
  for (size_t j = 0; j < by_point.size(); ++j) {
    const auto match = static_cast<size_t>(by_point[j].second);
    const double match_score = score(match);
    const int64_t keypoint_then_match =
        static_cast<int64_t>(predictions.keypoints[match]) << 32 | static_cast<int64_t>(match);
    if (j == 0 || by_point[j].first != by_point[j - 1].first) {
      kept.emplace_back(keypoint_then_match, 0);
      kept_score = match_score;
    } else if (match_score > kept_score) {
      kept.back().first = keypoint_then_match;
      kept_score = match_score;
    }
  }
  StableSortByKey(kept, scratch);
  std::vector<size_t> kept_matches(kept.size());
  for (size_t j = 0; j < kept.size(); ++j) kept_matches[j] = kept[j].first & 0xffffffff;
  return SelectMatches(predictions, kept_matches);
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
