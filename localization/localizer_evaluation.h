// What the Localizer keeps of one query while its candidates are matched and posed: shared by
// the stages in localizer.cc and the pose stage in localizer_pose_stage.cc, not part of the API.
#pragma once

#include <cstddef>
#include <vector>

#include "localization/localizer.h"
#include "localization/pooled_matches.h"

namespace hscloc {

// Candidates posed side by side (Localizer::PoseTogether), each against the best pose before its
// group: two keep this machine's two cores busy through a query's tail of failing candidates,
// while a candidate lacks at most one other's inliers to stop on. A constant, not the thread
// count, so that the poses are the same on every machine.
inline constexpr size_t kCandidatesPosedTogether = 2;

// What EvaluateCandidates fills in as candidates are matched and posed.
struct Localizer::Evaluation {
  PoseResult result;
  // One per candidate, after FilterVisible: every prediction, rivals for a point included (for
  // RefineRoundWinner; empty where the matcher has no rivals or the options keep every keypoint).
  std::vector<CandidateMatches> predictions;
  std::vector<CandidateMatches> matches;        // one per candidate, as posed
  std::vector<std::vector<char>> inlier_masks;  // one per candidate, empty until posed
  // One per candidate: it drew its first look's samples only (CompleteFirstLooks draws the rest).
  std::vector<char> first_look_only;
  // Candidates of the first retrieval round: [0, first_round_candidates).
  size_t first_round_candidates = 0;
  // The network's descriptor-only layers, run once for the query's every prediction.
  DescriptorLayerCache network_cache;
};

// The final pose and the matches it rests on (PoolAgreeingCandidates).
struct Localizer::FinalMatches {
  Rigid3d cam_from_world;
  int num_inliers = 0;
  CandidateMatches matches;
  std::vector<char> inlier_mask;
  int num_candidates = 1;
};

}  // namespace hscloc
