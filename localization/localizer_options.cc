// The localizer's options: their names on the command line and their checks.
#include "localization/localizer.h"
#include "util/check.h"

namespace hscloc {

Matcher ParseMatcher(const std::string& name) {
  if (name == "hsc") return Matcher::kNetwork;
  if (name == "nn") return Matcher::kNearestNeighbor;
  if (name == "auto") return Matcher::kAuto;
  ThrowInvalidArgument("unknown matcher '{}' (hsc, nn, auto)", name);
}

std::string MatcherName(Matcher matcher) {
  switch (matcher) {
    case Matcher::kNetwork:
      return "hsc";
    case Matcher::kNearestNeighbor:
      return "nn";
    case Matcher::kAuto:
      return "auto";
  }
  return "?";
}

CandidateSearch ParseCandidateSearch(const std::string& name) {
  if (name == "all") return CandidateSearch::kAll;
  if (name == "until-accepted") return CandidateSearch::kUntilAccepted;
  ThrowInvalidArgument("unknown candidate search '{}' (all, until-accepted)", name);
}

std::string CandidateSearchName(CandidateSearch search) {
  return search == CandidateSearch::kAll ? "all" : "until-accepted";
}

FinalPose ParseFinalPose(const std::string& name) {
  if (name == "winner") return FinalPose::kWinner;
  if (name == "pooled") return FinalPose::kPooled;
  ThrowInvalidArgument("unknown final pose '{}' (winner, pooled)", name);
}

std::string FinalPoseName(FinalPose final_pose) {
  return final_pose == FinalPose::kWinner ? "winner" : "pooled";
}

RetrievalMode ParseRetrievalMode(const std::string& name) {
  if (name == "global") return RetrievalMode::kGlobal;
  if (name == "global-then-votes") return RetrievalMode::kGlobalThenVotes;
  if (name == "votes") return RetrievalMode::kVotes;
  ThrowInvalidArgument("unknown retrieval '{}' (global, global-then-votes, votes)", name);
}

std::string RetrievalModeName(RetrievalMode mode) {
  switch (mode) {
    case RetrievalMode::kGlobal:
      return "global";
    case RetrievalMode::kGlobalThenVotes:
      return "global-then-votes";
    case RetrievalMode::kVotes:
      return "votes";
  }
  return "unknown";
}

void LocalizerOptions::Check() const {
  THROW_CHECK_MSG(final_pose == FinalPose::kWinner || final_pose == FinalPose::kPooled,
                  "LocalizerOptions.final_pose = {}, not a known final pose",
                  static_cast<int>(final_pose));
  THROW_CHECK_MSG(top_k >= 1 && top_k <= 1000, "LocalizerOptions.top_k = {} (1 .. 1000)", top_k);
  THROW_CHECK_MSG(accept_candidate_inliers >= 1, "LocalizerOptions.accept_candidate_inliers = {}",
                  accept_candidate_inliers);
  THROW_CHECK_MSG(vote_retrieval_below_inliers >= 0,
                  "LocalizerOptions.vote_retrieval_below_inliers = {}",
                  vote_retrieval_below_inliers);
  THROW_CHECK_MSG(deeper_global_candidates >= 0,
                  "LocalizerOptions.deeper_global_candidates = {} (0: none)",
                  deeper_global_candidates);
  THROW_CHECK_MSG(nearest_point_candidates >= 0,
                  "LocalizerOptions.nearest_point_candidates = {} (0: never)",
                  nearest_point_candidates);
  THROW_CHECK_MSG(nearest_point_widened_candidates >= 0,
                  "LocalizerOptions.nearest_point_widened_candidates = {} (0: no second pass)",
                  nearest_point_widened_candidates);
  THROW_CHECK_MSG(
      nearest_point_shortlist >= 0,
      "LocalizerOptions.nearest_point_shortlist = {} (0: every image on every keypoint)",
      nearest_point_shortlist);
  THROW_CHECK_MSG(max_matched_keypoints == 0 || max_matched_keypoints >= 4,
                  "LocalizerOptions.max_matched_keypoints = {} (0: every keypoint; a pose needs 4)",
                  max_matched_keypoints);
  THROW_CHECK_MSG(first_look_samples >= 0, "LocalizerOptions.first_look_samples = {} (0: none)",
                  first_look_samples);
  nearest_neighbor.Check();
  pose.Check();
}

}  // namespace hscloc
