// The Localizer's pose stage: RANSAC per candidate, the rest of the budget after first looks,
// the round winner's rivals, and the final pose pooled over the candidates that agree.
#include <algorithm>
#include <numeric>
#include <utility>

#include "localization/localizer.h"
#include "localization/localizer_evaluation.h"
#include "localization/pooled_matches.h"
#include "localization/rival_matches.h"
#include "model/network.h"
#include "util/parallel.h"

namespace hscloc {

namespace {

// The matches' order by confidence, most confident first (ties: in match order).
std::vector<size_t> MostConfidentFirst(const CandidateMatches& matches) {
  std::vector<size_t> order(matches.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return matches.confidences[a] > matches.confidences[b];
  });
  return order;
}

// Whether RANSAC samples these matches by confidence (LocalizerOptions::sample_by_confidence).
bool SampledByConfidence(const CandidateMatches& matches, const LocalizerOptions& options) {
  return options.sample_by_confidence && !matches.confidences.empty();
}

}  // namespace

AbsolutePoseResult Localizer::Pose(const LocalizationQuery& query, const CandidateMatches& matches,
                                   const LocalizerOptions& options, int inliers_to_beat) const {
  AbsolutePoseOptions pose_options = options.pose;
  pose_options.inliers_to_beat = inliers_to_beat;
  if (!SampledByConfidence(matches, options)) {
    return EstimateAbsolutePose(query.camera, KeypointPixels(query, matches),
                                PointPositions(matches), pose_options);
  }
  // PROSAC draws from the front of the list: the most confident matches first.
  pose_options.progressive_sampling = true;
  const std::vector<size_t> order = MostConfidentFirst(matches);
  const CandidateMatches ordered = SelectMatches(matches, order);
  AbsolutePoseResult pose = EstimateAbsolutePose(query.camera, KeypointPixels(query, ordered),
                                                 PointPositions(ordered), pose_options);
  std::vector<char> inlier_mask(matches.size(), 0);
  for (size_t i = 0; i < order.size(); ++i) inlier_mask[order[i]] = pose.inlier_mask[i];
  pose.inlier_mask = std::move(inlier_mask);
  return pose;
}

std::vector<AbsolutePoseResult> Localizer::PoseTogether(const LocalizationQuery& query,
                                                        const std::vector<size_t>& group,
                                                        const LocalizerOptions& options,
                                                        const Evaluation& evaluation) const {
  // Only a pose with more inliers than the best so far can win: RANSAC need not sample for less.
  const std::vector<LocalizationCandidate>& candidates = evaluation.result.candidates;
  const int best = Choose(candidates);
  const int inliers_to_beat = best >= 0 ? candidates[best].num_inliers : 0;
  std::vector<AbsolutePoseResult> poses(group.size());
  ParallelFor(group.size(), ComputeThreads(), [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      poses[i] = Pose(query, evaluation.matches[group[i]], options, inliers_to_beat);
    }
  });
  return poses;
}

void Localizer::RefineRoundWinner(const LocalizationQuery& query, const LocalizerOptions& options,
                                  size_t begin, Evaluation& evaluation) const {
  const std::vector<LocalizationCandidate>& candidates = evaluation.result.candidates;
  const int round_best = Choose(candidates, begin);
  if (round_best < 0) return;
  const auto best = static_cast<size_t>(round_best);
  const CandidateMatches& predictions = evaluation.predictions[best];
  LocalizationCandidate& candidate = evaluation.result.candidates[best];
  // No rivals: every point had one keypoint, or the matcher or options left none.
  if (predictions.size() == 0 || predictions.size() == evaluation.matches[best].size()) return;
  CandidateMatches nearest = NearestKeypointPerPoint(
      predictions, query.keypoints, query.camera, candidate.cam_from_world, map_->scene().points);
  if (nearest.keypoints == evaluation.matches[best].keypoints) return;
  AbsolutePoseResult pose =
      RefineAbsolutePoseFrom(query.camera, KeypointPixels(query, nearest), PointPositions(nearest),
                             candidate.cam_from_world, options.pose);
  // Re-choosing by reprojection keeps every inlier of the pose it starts from (a point's nearest
  // rival is within the threshold when any is); fewer after refinement means it went astray.
  if (!pose.success || pose.num_inliers < candidate.num_inliers) return;
  candidate.num_inliers = pose.num_inliers;
  candidate.cam_from_world = pose.cam_from_world;
  evaluation.matches[best] = std::move(nearest);
  evaluation.inlier_masks[best] = std::move(pose.inlier_mask);
}

std::vector<size_t> Localizer::AgreeingCandidates(const LocalizationQuery& query,
                                                  const LocalizerOptions& options,
                                                  const Evaluation& evaluation,
                                                  const Rigid3d& winner_pose) const {
  const auto best = static_cast<size_t>(evaluation.result.best_candidate);
  // A candidate agrees when the winner's pose explains as many of its matches as a pose needs:
  // a measure in pixels, whatever the map's scale, that a wrong image's matches rarely pass.
  AbsolutePoseOptions counting = options.pose;
  counting.refine = false;
  std::vector<size_t> agreeing = {best};
  for (size_t k = 0; k < evaluation.matches.size(); ++k) {
    const CandidateMatches& matches = evaluation.matches[k];
    if (k == best || static_cast<int>(matches.size()) < options.pose.min_inliers) continue;
    const AbsolutePoseResult under_winner =
        RefineAbsolutePoseFrom(query.camera, KeypointPixels(query, matches),
                               PointPositions(matches), winner_pose, counting);
    if (under_winner.success) agreeing.push_back(k);
  }
  return agreeing;
}

Localizer::FinalMatches Localizer::PoolAgreeingCandidates(const LocalizationQuery& query,
                                                          const LocalizerOptions& options,
                                                          Evaluation& evaluation) const {
  const auto best = static_cast<size_t>(evaluation.result.best_candidate);
  const LocalizationCandidate& winner = evaluation.result.candidates[best];
  FinalMatches final{winner.cam_from_world, winner.num_inliers, std::move(evaluation.matches[best]),
                     std::move(evaluation.inlier_masks[best])};
  if (options.final_pose == FinalPose::kWinner) return final;
  // The rows are the network's: the nearest-neighbour baseline pools its own matches.
  if (point_row_matcher_ != nullptr && options.matcher == Matcher::kNetwork) {
    return PoolPointRowMatches(query, options, evaluation, std::move(final));
  }
  const std::vector<size_t> agreeing =
      AgreeingCandidates(query, options, evaluation, winner.cam_from_world);
  if (agreeing.size() == 1) return final;
  // With the network's rival keypoints, all of them: the pooled pose chooses among them.
  std::vector<const CandidateMatches*> parts;
  for (const size_t k : agreeing) {
    const CandidateMatches& matches = k == best ? final.matches : evaluation.matches[k];
    parts.push_back(evaluation.predictions[k].size() > 0 ? &evaluation.predictions[k] : &matches);
  }
  CandidateMatches pooled = UniteMatches(parts);
  const Rigid3d start = final.cam_from_world;
  const int inliers_needed = final.num_inliers;
  return RefineOverPool(query, options, std::move(pooled), start, inliers_needed,
                        static_cast<int>(agreeing.size()), std::move(final));
}

Localizer::FinalMatches Localizer::PoolPointRowMatches(const LocalizationQuery& query,
                                                       const LocalizerOptions& options,
                                                       const Evaluation& evaluation,
                                                       FinalMatches network_final) const {
  const std::vector<LocalizationCandidate>& candidates = evaluation.result.candidates;
  const auto best = static_cast<size_t>(evaluation.result.best_candidate);
  // Image by image, as nearest neighbour matches: against the points of all of them at once, the
  // ratio test met more rivals and placed Lund's XFeat queries worse (docs/decisions.md).
  const DescriptorMatrix unit_query = UnitRows(query.descriptors);
  const Visibility& visibility = map_->visibility();
  const auto match_rows = [&](size_t k) {
    const uint32_t image = candidates[k].image_index;
    return point_row_matcher_->Match(unit_query,
                                     {visibility.PointsBegin(image), visibility.PointsEnd(image)},
                                     options.nearest_neighbor);
  };
  std::vector<CandidateMatches> rematched = {match_rows(best)};
  // The winner's pose from its own row matches, as nearest neighbour poses an image. Refined from
  // the pose of the network's matches, the final pose stayed in that pose's basin, which moved
  // with the training seed and budget (Lund XFeat medians 0.98-1.85x nearest neighbour's; from
  // the row matches' own pose 1.12-1.13x on every seed and budget; docs/decisions.md).
  Rigid3d start = network_final.cam_from_world;
  if (static_cast<int>(rematched.front().size()) >= options.pose.min_inliers) {
    const AbsolutePoseResult own = Pose(query, rematched.front(), options, /*inliers_to_beat=*/0);
    if (own.success) start = own.cam_from_world;
  }
  const std::vector<size_t> agreeing = AgreeingCandidates(query, options, evaluation, start);
  for (size_t i = 1; i < agreeing.size(); ++i) rematched.push_back(match_rows(agreeing[i]));
  std::vector<const CandidateMatches*> parts;
  for (const CandidateMatches& matches : rematched) parts.push_back(&matches);
  // Matches of the point rows are fewer than the network's: a pose needs its minimum of them.
  return RefineOverPool(query, options, UniteMatches(parts), start, options.pose.min_inliers,
                        static_cast<int>(agreeing.size()), std::move(network_final));
}

Localizer::FinalMatches Localizer::RefineOverPool(const LocalizationQuery& query,
                                                  const LocalizerOptions& options,
                                                  CandidateMatches pooled, const Rigid3d& start,
                                                  int inliers_needed, int num_candidates,
                                                  FinalMatches fallback) const {
  // Rivals for a point, from one candidate or several: the one the start reprojects nearest
  // stands for it (on Lund with SIFT, 25.jpg: 33 -> 38 inliers, 0.269 -> 0.221 m).
  if (!pooled.confidences.empty()) {
    pooled =
        NearestKeypointPerPoint(pooled, query.keypoints, query.camera, start, map_->scene().points);
  }
  // Refined from the start, not a new RANSAC: on the small city a RANSAC over the pool let a
  // query whose inliers fill a narrow strip at one depth slide from 0.32 m to 4.3 m off for 2 more
  // inliers; started from the winner, the refinement stays in its basin.
  AbsolutePoseResult pose = RefineAbsolutePoseFrom(query.camera, KeypointPixels(query, pooled),
                                                   PointPositions(pooled), start, options.pose);
  if (!pose.success || pose.num_inliers < inliers_needed) return fallback;
  return {pose.cam_from_world, pose.num_inliers, std::move(pooled), std::move(pose.inlier_mask),
          num_candidates};
}

bool Localizer::CompleteFirstLooks(const LocalizationQuery& query, const LocalizerOptions& options,
                                   Evaluation& evaluation) const {
  const std::vector<char>& unfinished = evaluation.first_look_only;
  if (std::find(unfinished.begin(), unfinished.end(), 1) == unfinished.end()) return false;
  std::vector<LocalizationCandidate>& candidates = evaluation.result.candidates;
  LocalizerOptions rest = options;
  rest.pose.max_iterations = options.pose.max_iterations - options.first_look_samples;
  // Other samples than the first look's.
  rest.pose.seed = options.pose.seed + 1;
  std::vector<size_t> order;
  for (const size_t k : PoseOrder(candidates, 0, candidates.size(), false)) {
    const bool later_round = k >= evaluation.first_round_candidates;
    if (later_round && SampledByConfidence(evaluation.matches[k], options)) continue;
    if (evaluation.first_look_only[k]) order.push_back(k);
  }
  bool improved = false;
  for (size_t first = 0; first < order.size(); first += kCandidatesPosedTogether) {
    std::vector<size_t> group;
    for (size_t i = first; i < std::min(order.size(), first + kCandidatesPosedTogether); ++i) {
      evaluation.first_look_only[order[i]] = 0;
      if (!CannotBeChosen(candidates, order[i])) group.push_back(order[i]);
    }
    std::vector<AbsolutePoseResult> poses = PoseTogether(query, group, rest, evaluation);
    for (size_t i = 0; i < group.size(); ++i) {
      AbsolutePoseResult& pose = poses[i];
      LocalizationCandidate& candidate = candidates[group[i]];
      candidate.ransac_samples += pose.num_iterations;
      if (!pose.success || pose.num_inliers <= candidate.num_inliers) continue;
      improved = true;
      candidate.pose_found = true;
      candidate.num_inliers = pose.num_inliers;
      candidate.cam_from_world = pose.cam_from_world;
      evaluation.inlier_masks[group[i]] = std::move(pose.inlier_mask);
    }
  }
  return improved;
}

int Localizer::Choose(const std::vector<LocalizationCandidate>& candidates, size_t begin) {
  int best = -1;
  for (size_t k = begin; k < candidates.size(); ++k) {
    if (candidates[k].pose_found &&
        (best < 0 || candidates[k].num_inliers > candidates[best].num_inliers)) {
      best = static_cast<int>(k);
    }
  }
  return best;
}

std::vector<size_t> Localizer::PoseOrder(const std::vector<LocalizationCandidate>& candidates,
                                         size_t begin, size_t end, bool in_retrieval_order) {
  std::vector<size_t> order(end - begin);
  std::iota(order.begin(), order.end(), begin);
  // The likely winner first, so that its inliers rule out the rest without their RANSAC.
  if (!in_retrieval_order) {
    std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
      return candidates[a].num_matches > candidates[b].num_matches;
    });
  }
  return order;
}

bool Localizer::CannotBeChosen(const std::vector<LocalizationCandidate>& candidates, size_t k) {
  const int best = Choose(candidates);
  if (best < 0) return false;
  // A pose's inliers are among its matches, and Choose keeps the first of equal candidates.
  const int best_inliers = candidates[best].num_inliers;
  const int matches = candidates[k].num_matches;
  return matches < best_inliers || (matches == best_inliers && k > static_cast<size_t>(best));
}

}  // namespace hscloc
