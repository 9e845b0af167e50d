// One keypoint per point among the network's predictions. The network sends each keypoint to a
// point, so several keypoints may land on one point; since a point is seen once in an image, at
// most one of them is right. Before a pose is known the most confident one stands for the point;
// once a pose is known, the one that pose reprojects nearest (on Lund with XFeat, 14 to 44 of a
// query's correct matches were rivals that lost on confidence: docs/decisions.md).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "localization/nearest_neighbor_matcher.h"
#include "scene/features.h"

namespace hscloc {

// The most confident keypoint of each point, in keypoint order (so that RANSAC's samples do not
// depend on the points' order); ties go to the first keypoint. Needs one confidence per match;
// throws std::invalid_argument otherwise.
CandidateMatches MostConfidentKeypointPerPoint(const CandidateMatches& predictions);

// The keypoint whose pixel is nearest to where `cam_from_world` reprojects each point, in keypoint
// order; a point behind the camera keeps its most confident keypoint. `keypoints` are the query's
// N x 2 pixels (COLMAP convention), `points` the map's points in world coordinates, indexed by
// CandidateMatches::point_indices.
CandidateMatches NearestKeypointPerPoint(const CandidateMatches& predictions,
                                         const KeypointMatrix& keypoints, const Camera& camera,
                                         const Rigid3d& cam_from_world,
                                         const std::vector<Eigen::Vector3d>& points);

}  // namespace hscloc
