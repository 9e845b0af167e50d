// The localization pipeline of the "Aachen hybrid" of Li et al., CVPR 2020, for one query, as
// named stages that data flows through in order:
//   Retrieve       the query's global descriptor (VLAD of its local descriptors, or the one it
//                  brings) -> the top-K database images of the map's index, the candidates;
//                  when none of them yields a pose (RetrievalMode::kGlobalThenVotes), a second
//                  round: the network's predictions without an image id vote for the images
//                  that observe the predicted points, and their top-K not yet tried follow;
//                  where that round is weak too, the global ranking's next candidates; where
//                  no round yields a pose, the network's last resort: the global ranking's
//                  first images ranked by their nearest-neighbour matches to the mean
//                  descriptors of the points they see (map/point_descriptors.h), the top-K so
//                  matched and posed
//   Match          the hierarchical classification network predicts, for each keypoint and each
//                  candidate, the 3D point it sees (the descriptor-only layers once, the K image
//                  ids as one batch); or, as the explicit-matching baseline, mutual nearest
//                  neighbours with a ratio test against each candidate's observations
//   FilterVisible  matches to points the candidate image does not observe are dropped
//   Pose           PnP-RANSAC and refinement per candidate (of the keypoints the network sends
//                  to one point, the most confident), the most matches first; a candidate with
//                  fewer matches than the best inliers so far cannot win and is not posed; then,
//                  for the round's best candidate, of those rival keypoints the one its pose
//                  reprojects nearest, and the pose refined again on them
//   Choose         the candidate pose with the most inliers wins
//   Pool           the matches of every candidate that agrees with the winner's pose, pooled,
//                  and the winner's pose refined over all their inliers (kept when it has at
//                  least the winner's inliers; FinalPose::kWinner keeps the paper's pose); where
//                  the network keeps several rows per point (a row per view), the winner is
//                  first matched again against the rows of the points its image sees, as nearest
//                  neighbour matches (point_row_matches.h), and posed anew from those matches;
//                  the candidates that pose explains are matched the same way and pooled
// Thread-safe: any number of threads may call Localize concurrently on one Localizer.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "localization/localization_map.h"
#include "localization/nearest_neighbor_matcher.h"
#include "localization/point_row_matches.h"
#include "localization/stage_timings.h"
#include "model/network.h"
#include "model/point_row_index.h"
#include "pose/absolute_pose.h"
#include "retrieval/point_votes.h"
#include "scene/features.h"

namespace hscloc {

// How the Localizer goes through the retrieved candidates (its early stop; RANSAC's own early stop
// is AbsolutePoseOptions::stop_sampling_past_inliers).
enum class CandidateSearch {
  kAll,            // every candidate is posed and the most inliers win (the paper)
  kUntilAccepted,  // candidates in retrieval order; the first with accept_candidate_inliers wins
};
// "all" or "until-accepted"; throws std::invalid_argument otherwise.
CandidateSearch ParseCandidateSearch(const std::string& name);
std::string CandidateSearchName(CandidateSearch search);

// Where the candidates come from (docs/decisions.md: "Retrieval by point votes").
enum class RetrievalMode {
  kGlobal,  // the global descriptor alone (the paper)
  // The global descriptor first; when its best candidate has fewer than
  // vote_retrieval_below_inliers inliers, the network's votes add up to top_k candidates more.
  // Without a network in the Localizer it is kGlobal.
  kGlobalThenVotes,
  kVotes,  // the network's votes alone, for every query (needs the network)
};
// "global", "global-then-votes" or "votes"; throws std::invalid_argument otherwise.
RetrievalMode ParseRetrievalMode(const std::string& name);
std::string RetrievalModeName(RetrievalMode mode);

// Which matches the final pose comes from (docs/decisions.md: "The final pose pools the candidates
// that agree").
enum class FinalPose {
  kWinner,  // the winning candidate's own pose, from the points its image sees (the paper)
  // The matches of the winner and of every candidate with at least AbsolutePoseOptions::
  // min_inliers inliers under the winner's pose, pooled (the network's rival keypoints of a point
  // settled by the winner's reprojection), and the winner's LO-RANSAC pose refined over all of
  // their inliers (RefineAbsolutePoseFrom); kept when it has at least the winner's inliers. With a
  // network of several rows per point, each of those candidates' matches are instead the query's
  // nearest neighbours among the rows of the points its image sees, and the refined pose is kept
  // when it has at least min_inliers inliers (fewer, cleaner matches than the network's own).
  kPooled,
};
// "winner" or "pooled"; throws std::invalid_argument otherwise.
FinalPose ParseFinalPose(const std::string& name);
std::string FinalPoseName(FinalPose final_pose);

enum class Matcher {
  kNetwork,          // the hierarchical scene coordinate classification network ("hsc")
  kNearestNeighbor,  // mutual nearest neighbours + ratio test against the image's observations
                     // ("nn")
  kAuto,             // the one the map found cheaper (localization/matcher_choice.h; "auto")
};
// "hsc", "nn" or "auto"; throws std::invalid_argument otherwise.
Matcher ParseMatcher(const std::string& name);
std::string MatcherName(Matcher matcher);

// Each of the last round's passes after the first ranks the global ranking's images up to this
// many times as deep as the pass before it (LocalizerOptions::nearest_point_widened_candidates).
inline constexpr int kNearestPointWideningFactor = 5;

// The keypoints the last round's shortlist counts its images on
// (LocalizerOptions::nearest_point_shortlist): about a quarter of an aachen night query's.
inline constexpr int64_t kNearestPointSampleKeypoints = 128;

struct LocalizerOptions {
  Matcher matcher = Matcher::kNetwork;
  // Retrieved database images, each a pose candidate (the paper: 10), per retrieval round.
  int top_k = 10;
  RetrievalMode retrieval = RetrievalMode::kGlobalThenVotes;
  // kGlobalThenVotes: a best candidate with fewer inliers than this calls for the votes' round,
  // as does a first round without any pose (even at 0).
  int vote_retrieval_below_inliers = 30;
  // kGlobalThenVotes: where the best candidate is still that weak after the votes' round (or,
  // without a network, after the first), the global ranking's next candidates not yet tried,
  // this many, are one more round: a night query's right image often ranks just past the first
  // top_k (hloc retrieves 50 for Aachen's night). Not where no round has a pose yet and the last
  // round follows (nearest_point_candidates), which ranks these images too. 0: none.
  int deeper_global_candidates = 20;
  // The network's last resort: where every round leaves the query without a pose, the global
  // ranking's first this many images are matched by mutual nearest neighbours with the ratio test
  // (nearest_neighbor) against the mean descriptors of the points each image sees
  // (map/point_descriptors.h), and the top_k with the most matches are posed as one more round. A
  // night descriptor the network cannot label still lies nearest its own point's mean, and hloc
  // retrieves 50 images for Aachen's night where this map's right image can rank past 100
  // (docs/decisions.md). Needs a map with point descriptors and global retrieval; 0: never.
  int nearest_point_candidates = 200;
  // The last round counts every image's matches on a sample of the query's keypoints first, and
  // all of them for this many images with the most: a night query's right image is among them
  // (docs/decisions.md), and a count is about linear in keypoints and in points. 0: every image
  // on every keypoint.
  int nearest_point_shortlist = 40;
  // Where the last round's nearest_point_candidates images give no pose either, it ranks the
  // global ranking's next images the same way, up to kNearestPointWideningFactor times as deep
  // per pass (200, 1,000, 5,000 by default), until a pass gives a pose or reaches this one: at
  // night the right image of an aachen query can rank past the 2,000th (docs/decisions.md), this
  // many is every image of an aachen-sized map (4,356), and a query no earlier pass placed is the
  // rare one. 0, or no more than nearest_point_candidates: no further pass.
  int nearest_point_widened_candidates = 5000;
  // Keypoints past this many are not matched: the network and every later stage see this many of
  // the query's, evenly spaced in its order (a detector's order by score is sampled across its
  // scores), while retrieval's global descriptor still pools them all. The network's work grows
  // with the keypoints and a pose needs tens of matches: on aachen a 4,096-keypoint day query
  // spends most of its time in the network (docs/decisions.md). 0: every keypoint.
  int max_matched_keypoints = 2048;
  // The votes' pass without an image id scores every point of the map at its first level; on a
  // map of at least PointRowIndex::kMinPoints points it probes the point row index instead
  // (model/point_row_index.h), unless this asks for the exact pass.
  bool exact_votes = false;
  // Drop matches to points the candidate image does not observe.
  bool visibility_filter = true;
  // Condition the network on the candidate's image id; off, it sees the "no image" id (an
  // ablation that needs a network trained with image dropout to be meaningful).
  bool use_image_id = true;
  // Restrict the network's choices at each level to subtrees the candidate image observes. A
  // network trained for it (NetworkOptions::masked_decoding) is always decoded so.
  bool visibility_masked_decoding = false;
  // Of the keypoints the network sends to one point, keep one, since a point is seen once in an
  // image: the most confident (the product of the chosen labels' probabilities) for RANSAC, then
  // the one the round's best pose reprojects nearest. Off, every prediction is a match (the
  // paper).
  bool one_keypoint_per_point = true;
  CandidateSearch candidate_search = CandidateSearch::kAll;
  FinalPose final_pose = FinalPose::kPooled;
  // Inliers with which kUntilAccepted accepts a candidate and stops.
  int accept_candidate_inliers = 100;
  // RANSAC samples a candidate first draws (of pose.max_iterations); a candidate that used them
  // all draws the rest only after every retrieval round (where no round gives a pose, after the
  // last round's first looks), and only for as long as it could still beat the best pose by then
  // (AbsolutePoseOptions::inliers_to_beat). A query whose global candidates are all wrong then
  // reaches the votes' round without sampling each of them to the full budget. 0: the full budget
  // at once.
  int first_look_samples = 500;
  // RANSAC samples the network's most confident matches first (PROSAC, AbsolutePoseOptions::
  // progressive_sampling); nearest neighbour, which has no confidences, samples uniformly. The
  // candidates of the rounds after the first (votes, the deeper global ranking) then draw their
  // first look only: sampled so, it found every pose that the whole budget found on aachen
  // (docs/decisions.md), and a query that no round can place no longer draws 5000 samples for each
  // of 40 images. The first round's candidates keep the paper's budget.
  bool sample_by_confidence = true;
  // The explicit-matching baseline's ratio test and mutuality.
  NearestNeighborOptions nearest_neighbor;
  AbsolutePoseOptions pose;

  // Throws std::invalid_argument naming the field.
  void Check() const;
};

struct LocalizationQuery {
  std::string name;
  Camera camera;
  KeypointMatrix keypoints;      // N x 2 pixels (COLMAP convention)
  DescriptorMatrix descriptors;  // N x D, D the map's descriptor dimension
  // The query's global descriptor for retrieval; required when the map has no VLAD encoder.
  std::optional<Eigen::VectorXf> global_descriptor;
};

enum class CandidateSource {
  kGlobalDescriptor,
  kPointVotes,
  // Ranked by their matches to the points' mean descriptors, and matched so
  // (LocalizerOptions::nearest_point_candidates); such an image may also be an earlier candidate.
  kNearestPoints,
};

// One retrieved database image and the pose estimated against it.
struct LocalizationCandidate {
  uint32_t image_index = 0;  // dense index in the map's scene
  image_t image_id = kInvalidImageId;
  CandidateSource source = CandidateSource::kGlobalDescriptor;
  float retrieval_score = 0;  // cosine of global descriptors, or summed vote weights
  // Matched and filtered; false when an early exit skipped it. A candidate with fewer matches
  // than the best pose's inliers is evaluated but not posed (CannotBeChosen: pose_found false).
  bool evaluated = false;
  int num_matches = 0;  // after the visibility filter
  int num_inliers = 0;
  bool pose_found = false;
  Rigid3d cam_from_world;
  // RANSAC samples drawn for it: its first look and, where drawn, the rest of its budget.
  int ransac_samples = 0;
};

struct PoseResult {
  bool success = false;
  std::string failure_reason;  // empty on success
  // The winning candidate's pose; on failure the top-1 retrieved image's pose when there is one.
  Rigid3d cam_from_world;
  int num_inliers = 0;
  int best_candidate = -1;  // index into candidates, -1 on failure
  // Candidates whose matches the final pose comes from: 1 for the winner alone, 0 on failure.
  int num_pooled_candidates = 0;
  std::vector<LocalizationCandidate> candidates;
  // The final pose's 2D-3D matches (the winner's, or the pool's): keypoint row, dense point index
  // (into the scene's points), inlier flag.
  std::vector<int> match_keypoints;
  std::vector<uint32_t> match_points;
  std::vector<char> match_inliers;
  StageTimings timings;
};

class Localizer {
 public:
  // `network` may be null when only the nearest-neighbour matcher is used; that matcher needs a map
  // loaded with its observations. Throws std::invalid_argument when the options need what the map
  // or network lacks, or the network does not fit the map.
  Localizer(std::shared_ptr<const LocalizationMap> map, std::shared_ptr<const Network> network,
            const LocalizerOptions& options = {});

  // Loads the bundle (with observations when the matcher needs them) and its network (when the
  // matcher or the retrieval uses it and the bundle has one).
  static Localizer FromBundle(const std::filesystem::path& bundle_dir,
                              const LocalizerOptions& options = {},
                              ComputeDevice device = ComputeDevice::kCpu);

  // Throws std::invalid_argument for a malformed query: descriptor dimension other than the map's,
  // keypoint and descriptor counts that differ, non-finite numbers, an invalid camera, no global
  // descriptor where the map has no VLAD encoder, or one of the wrong dimension. Failing to
  // localize is a result (success = false), not an exception.
  PoseResult Localize(const LocalizationQuery& query) const;
  // With per-query options (e.g. a client's top_k); they are checked against the map as above.
  PoseResult Localize(const LocalizationQuery& query, const LocalizerOptions& options) const;

  // The matcher `requested` runs on this map: kAuto resolved (ResolveMatcher), the others as
  // they are.
  Matcher ResolvedMatcher(Matcher requested) const;
  const LocalizationMap& map() const { return *map_; }
  const LocalizerOptions& options() const { return options_; }
  const Network* network() const { return network_.get(); }

 private:
  struct Evaluation;

  void CheckOptionsFit(const LocalizerOptions& options) const;
  void CheckQuery(const LocalizationQuery& query) const;

  // The stages (see the top of this file).
  // The global ranking's first `count` images except those in `tried`.
  std::vector<LocalizationCandidate> Retrieve(
      const Eigen::VectorXf& global_descriptor, int count,
      const std::vector<LocalizationCandidate>& tried) const;
  // The top_k images the network's votes rank highest, except those in `tried`. `network_cache`
  // holds the query's descriptor-only layers across the network's calls.
  std::vector<LocalizationCandidate> RetrieveByVotes(
      const LocalizationQuery& query, const LocalizerOptions& options,
      const std::vector<LocalizationCandidate>& tried, DescriptorLayerCache& network_cache) const;
  // The first round's candidates into the evaluation, by the network's votes
  // (RetrievalMode::kVotes) or by the global descriptor, encoded here where the query brings none;
  // returns that descriptor (empty with the votes alone).
  Eigen::VectorXf RetrieveFirstRound(const LocalizationQuery& query,
                                     const LocalizerOptions& options, Evaluation& evaluation) const;
  // The rounds after the global descriptor's first (RetrievalMode::kGlobalThenVotes): the votes'
  // where the best candidate so far is below vote_retrieval_below_inliers, then the global
  // ranking's next deeper_global_candidates images where it still is.
  void EvaluateFurtherRounds(const LocalizationQuery& query, const LocalizerOptions& options,
                             const Eigen::VectorXf& global_descriptor,
                             Evaluation& evaluation) const;
  // Whether the query's retrieval has a votes round: always, after a weak first one, or never.
  bool UsesVotes(const LocalizerOptions& options) const;
  // The last round (LocalizerOptions::nearest_point_candidates), when no candidate so far has a
  // pose: the global ranking's first images matched against their points' mean descriptors, the
  // top_k with the most matches posed.
  void EvaluateNearestPointRound(const LocalizationQuery& query, const LocalizerOptions& options,
                                 const Eigen::VectorXf& global_descriptor,
                                 Evaluation& evaluation) const;
  // One pass of the last round over the global ranking's images [first_rank, end_rank).
  void EvaluateNearestPointRanks(const LocalizationQuery& query, const LocalizerOptions& options,
                                 const Eigen::VectorXf& global_descriptor, int first_rank,
                                 int end_rank, Evaluation& evaluation) const;
  bool UsesNearestPoints(const LocalizerOptions& options) const;
  // Whether the last round runs: it is used and no candidate so far has a pose.
  bool LastRoundFollows(const LocalizerOptions& options, const Eigen::VectorXf& global_descriptor,
                        const Evaluation& evaluation) const;
  // Whether the last round follows and ranks every image the deeper global round would pose, so
  // that the deeper round is left to it.
  bool LastRoundHoldsDeeperRound(const LocalizerOptions& options,
                                 const Eigen::VectorXf& global_descriptor,
                                 const Evaluation& evaluation) const;
  // The top_k of the global ranking's images [first_rank, end_rank) with the most nearest-point
  // matches, and at least pose.min_inliers of them.
  std::vector<LocalizationCandidate> RetrieveByNearestPoints(
      const LocalizationQuery& query, const LocalizerOptions& options,
      const Eigen::VectorXf& global_descriptor, int first_rank, int end_rank) const;
  // Localize on max_matched_keypoints of the query's keypoints
  // (LocalizerOptions::max_matched_keypoints), the matches reported by the query's own keypoint
  // rows.
  PoseResult LocalizeKeypointSample(const LocalizationQuery& query,
                                    const LocalizerOptions& options) const;
  // About how many matches MatchNearestPoints finds in each of `images`, the union of their
  // points matched once in 8-bit integers (CountNearestRowMatches).
  std::vector<int> CountNearestPointMatches(const DescriptorMatrix& descriptors,
                                            const std::vector<LocalizationCandidate>& images,
                                            const LocalizerOptions& options) const;
  // `images` by their CountNearestPointMatches, most first (ties in their order).
  void RankByNearestPointMatches(const DescriptorMatrix& descriptors,
                                 const LocalizerOptions& options,
                                 std::vector<LocalizationCandidate>& images) const;
  // The nearest_point_shortlist of `images` with the most matches of kNearestPointSampleKeypoints
  // of the query's keypoints, evenly spaced, in the order of `images`; all of them where they are
  // no more, or the query has no more keypoints than the sample.
  std::vector<LocalizationCandidate> ShortlistForNearestPoints(
      const DescriptorMatrix& descriptors, std::vector<LocalizationCandidate> images,
      const LocalizerOptions& options) const;
  // Mutual nearest neighbours with the ratio test between unit query rows and the mean
  // descriptors of the points image `image_index` sees.
  CandidateMatches MatchNearestPoints(const DescriptorMatrix& unit_query, uint32_t image_index,
                                      const LocalizerOptions& options) const;
  // The matches of candidates [begin, end), one entry each.
  std::vector<CandidateMatches> Match(const LocalizationQuery& query,
                                      const std::vector<LocalizationCandidate>& candidates,
                                      size_t begin, size_t end, const LocalizerOptions& options,
                                      DescriptorLayerCache& network_cache) const;
  CandidateMatches FilterVisible(uint32_t image_index, CandidateMatches matches) const;
  // RANSAC and refinement of one candidate's matches; a pose with at most `inliers_to_beat`
  // inliers is not sampled for (AbsolutePoseOptions::inliers_to_beat).
  AbsolutePoseResult Pose(const LocalizationQuery& query, const CandidateMatches& matches,
                          const LocalizerOptions& options, int inliers_to_beat) const;
  // Pose for each of candidates `group`, side by side on the compute threads, each against the
  // best pose found before the group: the poses do not depend on the number of threads.
  std::vector<AbsolutePoseResult> PoseTogether(const LocalizationQuery& query,
                                               const std::vector<size_t>& group,
                                               const LocalizerOptions& options,
                                               const Evaluation& evaluation) const;
  // The pose of the round's best candidate (the round's candidates start at `begin`) refined once
  // more, each point now taking the rival keypoint the pose reprojects nearest (rival_matches.h);
  // kept when it has at least as many inliers.
  void RefineRoundWinner(const LocalizationQuery& query, const LocalizerOptions& options,
                         size_t begin, Evaluation& evaluation) const;
  static std::vector<Eigen::Vector2d> KeypointPixels(const LocalizationQuery& query,
                                                     const CandidateMatches& matches);
  std::vector<Eigen::Vector3d> PointPositions(const CandidateMatches& matches) const;
  // The candidates of one retrieval round evaluated as the options' candidate search says.
  void EvaluateRound(const LocalizationQuery& query, const LocalizerOptions& options, size_t begin,
                     Evaluation& evaluation) const;
  // Match, FilterVisible and Pose for candidates [begin, end) of the evaluation; with
  // `stop_when_accepted`, posing stops at the first candidate with accept_candidate_inliers.
  void EvaluateCandidates(const LocalizationQuery& query, const LocalizerOptions& options,
                          size_t begin, size_t end, bool stop_when_accepted,
                          Evaluation& evaluation) const;
  // The rest of the RANSAC budget for the candidates that drew only their first look, each kept
  // when it finds a pose with more inliers; true when one was.
  bool CompleteFirstLooks(const LocalizationQuery& query, const LocalizerOptions& options,
                          Evaluation& evaluation) const;
  // The order in which candidates [begin, end) are posed: retrieval order, or the most matches
  // first.
  static std::vector<size_t> PoseOrder(const std::vector<LocalizationCandidate>& candidates,
                                       size_t begin, size_t end, bool in_retrieval_order);
  // True when candidate k, matched but not yet posed, cannot beat the best pose so far, whatever
  // its RANSAC finds: its pose is then not estimated, which leaves the winner and the final pose
  // as they would be.
  static bool CannotBeChosen(const std::vector<LocalizationCandidate>& candidates, size_t k);
  // The round winner (evaluation.result.best_candidate) and the candidates `winner_pose`
  // explains: those with at least AbsolutePoseOptions::min_inliers of their matches within the
  // threshold.
  std::vector<size_t> AgreeingCandidates(const LocalizationQuery& query,
                                         const LocalizerOptions& options,
                                         const Evaluation& evaluation,
                                         const Rigid3d& winner_pose) const;
  // The final pose and its matches, from the winner alone or pooled as options.final_pose says.
  struct FinalMatches;
  FinalMatches PoolAgreeingCandidates(const LocalizationQuery& query,
                                      const LocalizerOptions& options,
                                      Evaluation& evaluation) const;
  // The pooled final pose of a network with several rows per point (point_row_matcher_): the
  // winner and the candidates that agree with it matched again against their points' rows, the
  // winner posed anew from its own row matches, and that pose refined over the union.
  // `network_final` (the winner as the network posed it) stands where that fails.
  FinalMatches PoolPointRowMatches(const LocalizationQuery& query, const LocalizerOptions& options,
                                   const Evaluation& evaluation, FinalMatches network_final) const;
  // `start` refined over `pooled` (one keypoint per point: the one `start` reprojects nearest);
  // `fallback` where the refinement fails or keeps fewer than `inliers_needed` inliers.
  FinalMatches RefineOverPool(const LocalizationQuery& query, const LocalizerOptions& options,
                              CandidateMatches pooled, const Rigid3d& start, int inliers_needed,
                              int num_candidates, FinalMatches fallback) const;
  // The candidate with the most inliers among those from `begin` on posed successfully; -1 when
  // none.
  static int Choose(const std::vector<LocalizationCandidate>& candidates, size_t begin = 0);

  std::shared_ptr<const LocalizationMap> map_;
  std::shared_ptr<const Network> network_;
  LocalizerOptions options_;
  // Prepared once, when the map has observations.
  std::shared_ptr<const NearestNeighborMatcher> nearest_neighbor_;
  // The network's point rows, for the pooled final pose, when it keeps several rows per point;
  // null otherwise.
  std::shared_ptr<const PointRowMatcher> point_row_matcher_;
  // Built when the network is there to vote.
  std::shared_ptr<const PointVoteIndex> point_votes_;
  // The network's point rows in lists, for the votes' first level on a large map; null otherwise.
  std::shared_ptr<const PointRowIndex> point_row_index_;
  Matcher auto_matcher_ = Matcher::kNetwork;  // what kAuto runs here
};

}  // namespace hscloc
