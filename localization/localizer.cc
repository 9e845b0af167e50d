#include "localization/localizer.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>

#include "localization/localizer_evaluation.h"
#include "localization/matcher_choice.h"
#include "localization/pooled_matches.h"
#include "localization/rival_matches.h"
#include "map/map_blobs.h"
#include "map/map_bundle.h"
#include "util/check.h"
#include "util/memory.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {
namespace {

PoseResult Finish(PoseResult result, std::string failure_reason, const Timer& total_timer) {
  result.failure_reason = std::move(failure_reason);
  result.timings.total_ms = total_timer.ElapsedMilliseconds();
  return result;
}

}  // namespace

Localizer::Localizer(std::shared_ptr<const LocalizationMap> map,
                     std::shared_ptr<const Network> network, const LocalizerOptions& options)
    : map_(std::move(map)), network_(std::move(network)), options_(options) {
  THROW_CHECK_MSG(map_ != nullptr, "Localizer: no map");
  // Every query allocates and frees the same megabytes of activations (docs/decisions.md).
  KeepFreedMemoryForReuse();
  const Scene& scene = map_->scene();
  if (network_ != nullptr) {
    const NetworkShape& shape = network_->shape();
    if (shape.descriptor_dim != map_->descriptor_dim() ||
        shape.num_images != static_cast<int>(scene.NumImages()) ||
        shape.levels != map_->label_tree().levels() ||
        shape.branching != map_->label_tree().branching()) {
      ThrowInvalidArgument(
          "{}: the network (D {}, {} images, {} levels x {}) does not fit the map (D {}, {} "
          "images, {} levels x {})",
          map_->dir().string(), shape.descriptor_dim, shape.num_images, shape.levels,
          shape.branching, map_->descriptor_dim(), scene.NumImages(), map_->label_tree().levels(),
          map_->label_tree().branching());
    }
  }
  if (scene.NumObservations() > 0) {
    nearest_neighbor_ = std::make_shared<const NearestNeighborMatcher>(scene);
  }
  if (network_ != nullptr) {
    point_votes_ = std::make_shared<const PointVoteIndex>(map_->visibility());
    if (network_->options().pooled_point_rows && network_->device() == ComputeDevice::kCpu &&
        network_->shape().nodes_per_depth.back() >= PointRowIndex::kMinPoints) {
      const Timer timer;
      point_row_index_ = std::make_shared<const PointRowIndex>(
          PointRowIndex::Build(*network_, map_->label_tree()));
      spdlog::info("point row index for the votes: {} lists over {} points in {:.2f} s",
                   point_row_index_->NumLists(), point_row_index_->NumPoints(),
                   timer.ElapsedSeconds());
    }
  }
  if (network_ != nullptr && !network_->shape().point_row_offsets.empty()) {
    point_row_matcher_ = std::make_shared<const PointRowMatcher>(*network_, map_->label_tree());
  }
  auto_matcher_ = ResolveMatcher(Matcher::kAuto, map_->metadata(), network_ != nullptr,
                                 nearest_neighbor_ != nullptr);
  CheckOptionsFit(options_);
}

Localizer Localizer::FromBundle(const std::filesystem::path& bundle_dir,
                                const LocalizerOptions& options, ComputeDevice device) {
  // What "auto" runs follows from the manifest alone, so that only what it needs is loaded.
  Matcher matcher = options.matcher;
  if (matcher == Matcher::kAuto) {
    const MapBundle manifest = MapBundle::Open(bundle_dir, std::vector<std::string>{});
    matcher = ResolveMatcher(matcher, manifest.metadata(), manifest.HasBlob(map_blobs::kNetwork),
                             manifest.HasBlob(map_blobs::kObservations));
  }
  auto map = LocalizationMap::Load(
      bundle_dir,
      {.load_observations = matcher == Matcher::kNearestNeighbor,
       .load_network = matcher == Matcher::kNetwork || options.retrieval != RetrievalMode::kGlobal,
       .load_point_descriptors =
           matcher == Matcher::kNetwork && options.nearest_point_candidates > 0,
       .device = device});
  std::shared_ptr<const Network> network = map->network();
  return Localizer(std::move(map), std::move(network), options);
}

Matcher Localizer::ResolvedMatcher(Matcher requested) const {
  return requested == Matcher::kAuto ? auto_matcher_ : requested;
}

void Localizer::CheckOptionsFit(const LocalizerOptions& options) const {
  options.Check();
  if (options.matcher == Matcher::kAuto && network_ == nullptr && nearest_neighbor_ == nullptr) {
    ThrowInvalidArgument(
        "{}: the map has neither a trained network nor its observations: no matcher can run",
        map_->dir().string());
  }
  if (options.matcher == Matcher::kNetwork && network_ == nullptr) {
    ThrowInvalidArgument("{}: the hsc matcher needs a trained network (run `hscloc train`)",
                         map_->dir().string());
  }
  if (options.retrieval == RetrievalMode::kVotes && network_ == nullptr) {
    ThrowInvalidArgument("{}: retrieval by votes needs a trained network (run `hscloc train`)",
                         map_->dir().string());
  }
  if (options.matcher == Matcher::kNearestNeighbor && nearest_neighbor_ == nullptr) {
    ThrowInvalidArgument(
        "{}: the nn matcher needs the map's observations (load the map with its observations)",
        map_->dir().string());
  }
}

void Localizer::CheckQuery(const LocalizationQuery& query) const {
  const std::string& name = query.name.empty() ? std::string("query") : query.name;
  try {
    query.camera.Check();
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: {}", name, error.what());
  }
  if (query.keypoints.rows() != query.descriptors.rows()) {
    ThrowInvalidArgument("{}: {} keypoints but {} descriptors", name, query.keypoints.rows(),
                         query.descriptors.rows());
  }
  if (query.descriptors.rows() > 0 && query.descriptors.cols() != map_->descriptor_dim()) {
    ThrowInvalidArgument("{}: descriptors of dimension {}, the map's are {}", name,
                         query.descriptors.cols(), map_->descriptor_dim());
  }
  if (!query.descriptors.allFinite()) ThrowInvalidArgument("{}: non-finite descriptor", name);
  for (int64_t i = 0; i < query.keypoints.rows(); ++i) {
    const Eigen::Vector2d keypoint = query.keypoints.row(i).transpose().cast<double>();
    if (!keypoint.allFinite() || !query.camera.IsInside(keypoint)) {
      ThrowInvalidArgument("{}: keypoint {} at ({}, {}) is outside the {} x {} image", name, i,
                           keypoint.x(), keypoint.y(), query.camera.width, query.camera.height);
    }
  }
  if (query.global_descriptor.has_value()) {
    if (query.global_descriptor->size() != map_->global_index().dimension()) {
      ThrowInvalidArgument("{}: global descriptor of dimension {}, the map's index has {}", name,
                           query.global_descriptor->size(), map_->global_index().dimension());
    }
    if (!query.global_descriptor->allFinite()) {
      ThrowInvalidArgument("{}: non-finite global descriptor", name);
    }
  } else if (!map_->vlad().has_value()) {
    ThrowInvalidArgument(
        "{}: the map's global descriptors came from an external model: the query must bring its "
        "global descriptor",
        name);
  }
}

PoseResult Localizer::Localize(const LocalizationQuery& query) const {
  return Localize(query, options_);
}

namespace {

bool AlreadyTried(const std::vector<LocalizationCandidate>& tried, uint32_t image_index) {
  return std::any_of(tried.begin(), tried.end(), [&](const LocalizationCandidate& candidate) {
    return candidate.image_index == image_index;
  });
}

}  // namespace

PoseResult Localizer::LocalizeKeypointSample(const LocalizationQuery& query,
                                             const LocalizerOptions& options) const {
  const Timer sample_timer;
  const int64_t count = query.keypoints.rows();
  const int64_t kept = options.max_matched_keypoints;
  LocalizationQuery sample{query.name, query.camera, KeypointMatrix(kept, 2),
                           DescriptorMatrix(kept, query.descriptors.cols()),
                           query.global_descriptor};
  std::vector<int> rows(kept);
  for (int64_t i = 0; i < kept; ++i) {
    rows[i] = static_cast<int>(i * count / kept);
    sample.keypoints.row(i) = query.keypoints.row(rows[i]);
    sample.descriptors.row(i) = query.descriptors.row(rows[i]);
  }
  if (!sample.global_descriptor.has_value() && options.retrieval != RetrievalMode::kVotes) {
    sample.global_descriptor = map_->vlad()->Encode(query.descriptors, ComputeThreads());
  }
  // The sample and the global descriptor of every keypoint count as retrieval's.
  const double sample_ms = sample_timer.ElapsedMilliseconds();
  PoseResult result = Localize(sample, options);
  for (int& keypoint : result.match_keypoints) keypoint = rows[keypoint];
  result.timings.retrieval_ms += sample_ms;
  result.timings.total_ms += sample_ms;
  return result;
}

std::vector<LocalizationCandidate> Localizer::Retrieve(
    const Eigen::VectorXf& global_descriptor, int count,
    const std::vector<LocalizationCandidate>& tried) const {
  std::vector<LocalizationCandidate> candidates;
  if (global_descriptor.size() == 0) return candidates;
  const int wanted = count + static_cast<int>(tried.size());
  for (const RetrievalHit& hit : map_->global_index().Search(global_descriptor, wanted)) {
    if (static_cast<int>(candidates.size()) == count) break;
    if (AlreadyTried(tried, hit.image_index)) continue;
    LocalizationCandidate candidate;
    candidate.image_index = static_cast<uint32_t>(hit.image_index);
    candidate.image_id = map_->scene().images[candidate.image_index].image_id;
    candidate.retrieval_score = hit.score;
    candidates.push_back(candidate);
  }
  return candidates;
}

bool Localizer::UsesVotes(const LocalizerOptions& options) const {
  return options.retrieval != RetrievalMode::kGlobal && network_ != nullptr;
}

std::vector<LocalizationCandidate> Localizer::RetrieveByVotes(
    const LocalizationQuery& query, const LocalizerOptions& options,
    const std::vector<LocalizationCandidate>& tried, DescriptorLayerCache& network_cache) const {
  std::vector<LocalizationCandidate> candidates;
  const int64_t num_keypoints = query.descriptors.rows();
  if (num_keypoints == 0) return candidates;
  // Without an image id the network ranks every point of the map (a network trained with image
  // dropout has learned to). Each prediction votes as much as the network is sure of it, divided
  // by the square root of the point's track length, so that a point seen from everywhere does not
  // outvote the rarer ones that place the query (as tf-idf weights words).
  const PointPredictions predictions =
      network_->Predict(query.descriptors, {network_->NoImageIndex()}, map_->label_tree(), nullptr,
                        &network_cache, options.exact_votes ? nullptr : point_row_index_.get());
  std::vector<int64_t> points(num_keypoints);
  std::vector<float> weights(num_keypoints, 0.0f);
  for (int64_t keypoint = 0; keypoint < num_keypoints; ++keypoint) {
    const int64_t point = predictions.point_indices(0, keypoint);
    points[keypoint] = point;
    if (point < 0) continue;
    const auto index = static_cast<uint32_t>(point);
    const auto track_length =
        static_cast<float>(point_votes_->ImagesEnd(index) - point_votes_->ImagesBegin(index));
    if (track_length > 0) {
      weights[keypoint] = predictions.confidences(0, keypoint) / std::sqrt(track_length);
    }
  }
  const std::vector<RetrievalHit> hits =
      point_votes_->Search(points, weights, options.top_k + static_cast<int>(tried.size()));
  for (const RetrievalHit& hit : hits) {
    if (static_cast<int>(candidates.size()) == options.top_k) break;
    if (AlreadyTried(tried, hit.image_index)) continue;
    LocalizationCandidate candidate;
    candidate.image_index = hit.image_index;
    candidate.image_id = map_->scene().images[hit.image_index].image_id;
    candidate.source = CandidateSource::kPointVotes;
    candidate.retrieval_score = hit.score;
    candidates.push_back(candidate);
  }
  return candidates;
}

std::vector<CandidateMatches> Localizer::Match(const LocalizationQuery& query,
                                               const std::vector<LocalizationCandidate>& candidates,
                                               size_t begin, size_t end,
                                               const LocalizerOptions& options,
                                               DescriptorLayerCache& network_cache) const {
  std::vector<CandidateMatches> matches(end - begin);
  // A round's candidates share their source: the last round's match the points' descriptors.
  const bool nearest_points =
      begin < end && candidates[begin].source == CandidateSource::kNearestPoints;
  if (nearest_points || options.matcher == Matcher::kNearestNeighbor) {
    const DescriptorMatrix unit_query = UnitRows(query.descriptors);
    for (size_t k = begin; k < end; ++k) {
      const uint32_t image = candidates[k].image_index;
      matches[k - begin] =
          nearest_points ? MatchNearestPoints(unit_query, image, options)
                         : nearest_neighbor_->Match(unit_query, image, options.nearest_neighbor);
    }
    return matches;
  }
  // Without image ids every candidate shares the one prediction of the "no image" index.
  std::vector<uint32_t> images;
  if (options.use_image_id) {
    for (size_t k = begin; k < end; ++k) images.push_back(candidates[k].image_index);
  } else {
    images.push_back(network_->NoImageIndex());
  }
  // A network trained with the visibility softmax ranks only the children an image sees.
  const bool masked = options.visibility_masked_decoding || network_->options().masked_decoding;
  const PointPredictions predictions =
      network_->Predict(query.descriptors, images, map_->label_tree(),
                        masked ? &map_->visibility() : nullptr, &network_cache);
  for (size_t k = begin; k < end; ++k) {
    const int64_t row = options.use_image_id ? static_cast<int64_t>(k - begin) : 0;
    CandidateMatches& candidate_matches = matches[k - begin];
    for (int64_t keypoint = 0; keypoint < query.descriptors.rows(); ++keypoint) {
      const int64_t point = predictions.point_indices(row, keypoint);
      if (point < 0) continue;
      candidate_matches.keypoints.push_back(static_cast<int>(keypoint));
      candidate_matches.point_indices.push_back(static_cast<uint32_t>(point));
      candidate_matches.confidences.push_back(predictions.confidences(row, keypoint));
    }
  }
  return matches;
}

CandidateMatches Localizer::FilterVisible(uint32_t image_index, CandidateMatches matches) const {
  size_t kept = 0;
  for (size_t i = 0; i < matches.size(); ++i) {
    if (map_->visibility().IsVisible(image_index, matches.point_indices[i])) {
      matches.keypoints[kept] = matches.keypoints[i];
      matches.point_indices[kept] = matches.point_indices[i];
      if (!matches.confidences.empty()) matches.confidences[kept] = matches.confidences[i];
      ++kept;
    }
  }
  matches.keypoints.resize(kept);
  matches.point_indices.resize(kept);
  if (!matches.confidences.empty()) matches.confidences.resize(kept);
  return matches;
}

std::vector<Eigen::Vector2d> Localizer::KeypointPixels(const LocalizationQuery& query,
                                                       const CandidateMatches& matches) {
  std::vector<Eigen::Vector2d> pixels;
  pixels.reserve(matches.size());
  for (const int keypoint : matches.keypoints) {
    pixels.push_back(query.keypoints.row(keypoint).transpose().cast<double>());
  }
  return pixels;
}

std::vector<Eigen::Vector3d> Localizer::PointPositions(const CandidateMatches& matches) const {
  std::vector<Eigen::Vector3d> positions;
  positions.reserve(matches.size());
  for (const uint32_t point : matches.point_indices) {
    positions.push_back(map_->scene().points[point]);
  }
  return positions;
}

void Localizer::EvaluateCandidates(const LocalizationQuery& query, const LocalizerOptions& options,
                                   size_t begin, size_t end, bool stop_when_accepted,
                                   Evaluation& evaluation) const {
  if (begin >= end) return;
  std::vector<LocalizationCandidate>& candidates = evaluation.result.candidates;
  StageTimings& timings = evaluation.result.timings;
  std::vector<CandidateMatches> matches;
  {
    ScopedTimer timer(&timings.match_ms);
    matches = Match(query, candidates, begin, end, options, evaluation.network_cache);
  }
  {
    ScopedTimer timer(&timings.visibility_ms);
    ParallelFor(end - begin, ComputeThreads(), [&](size_t first, size_t last) {
      for (size_t k = begin + first; k < begin + last; ++k) {
        CandidateMatches& candidate_matches = matches[k - begin];
        if (options.visibility_filter) {
          candidate_matches =
              FilterVisible(candidates[k].image_index, std::move(candidate_matches));
        }
        // A point is seen once in an image: its most confident keypoint stands for it until a
        // pose is known (RefineRoundWinner).
        if (options.one_keypoint_per_point && !candidate_matches.confidences.empty()) {
          evaluation.matches[k] = MostConfidentKeypointPerPoint(candidate_matches);
          evaluation.predictions[k] = std::move(candidate_matches);
        } else {
          evaluation.matches[k] = std::move(candidate_matches);
        }
        candidates[k].num_matches = static_cast<int>(evaluation.matches[k].size());
      }
    });
  }
  ScopedTimer timer(&timings.pose_ms);
  LocalizerOptions first_look = options;
  const bool limited =
      options.first_look_samples > 0 && options.first_look_samples < options.pose.max_iterations;
  if (limited) first_look.pose.max_iterations = options.first_look_samples;
  const std::vector<size_t> order = PoseOrder(candidates, begin, end, stop_when_accepted);
  // The early exit decides after every candidate.
  const size_t group_size = stop_when_accepted ? 1 : kCandidatesPosedTogether;
  for (size_t first = 0; first < order.size(); first += group_size) {
    std::vector<size_t> group;
    for (size_t i = first; i < std::min(order.size(), first + group_size); ++i) {
      // Matched: even when it is not posed, its matches may still join the pool.
      candidates[order[i]].evaluated = true;
      if (!CannotBeChosen(candidates, order[i])) group.push_back(order[i]);
    }
    std::vector<AbsolutePoseResult> poses = PoseTogether(query, group, first_look, evaluation);
    bool accepted = false;
    for (size_t i = 0; i < group.size(); ++i) {
      AbsolutePoseResult& pose = poses[i];
      const size_t k = group[i];
      evaluation.first_look_only[k] =
          limited && pose.num_iterations >= first_look.pose.max_iterations;
      LocalizationCandidate& candidate = candidates[k];
      candidate.ransac_samples = pose.num_iterations;
      candidate.pose_found = pose.success;
      candidate.num_inliers = pose.success ? pose.num_inliers : 0;
      candidate.cam_from_world = pose.cam_from_world;
      evaluation.inlier_masks[k] = std::move(pose.inlier_mask);
      accepted = accepted || candidate.num_inliers >= options.accept_candidate_inliers;
    }
    if (stop_when_accepted && accepted) break;
  }
}

void Localizer::EvaluateRound(const LocalizationQuery& query, const LocalizerOptions& options,
                              size_t begin, Evaluation& evaluation) const {
  const size_t end = evaluation.result.candidates.size();
  evaluation.predictions.resize(end);
  evaluation.matches.resize(end);
  evaluation.inlier_masks.resize(end);
  evaluation.first_look_only.resize(end, 0);
  if (begin >= end) return;
  if (options.candidate_search == CandidateSearch::kAll) {
    EvaluateCandidates(query, options, begin, end, /*stop_when_accepted=*/false, evaluation);
  } else {
    // The first candidate alone: when retrieval is right it settles the query, and the network
    // runs on one image id instead of K. The rest follow as one batch only when it does not.
    EvaluateCandidates(query, options, begin, begin + 1, /*stop_when_accepted=*/false, evaluation);
    if (evaluation.result.candidates[begin].num_inliers < options.accept_candidate_inliers) {
      EvaluateCandidates(query, options, begin + 1, end, /*stop_when_accepted=*/true, evaluation);
    }
  }
  ++evaluation.result.timings.rounds;
  ScopedTimer timer(&evaluation.result.timings.pose_ms);
  ScopedTimer refine_timer(&evaluation.result.timings.refine_ms);
  RefineRoundWinner(query, options, begin, evaluation);
}

void Localizer::EvaluateFurtherRounds(const LocalizationQuery& query,
                                      const LocalizerOptions& options,
                                      const Eigen::VectorXf& global_descriptor,
                                      Evaluation& evaluation) const {
  PoseResult& result = evaluation.result;
  const auto weak = [&] {
    const int best = Choose(result.candidates);
    return best < 0 || result.candidates[best].num_inliers < options.vote_retrieval_below_inliers;
  };
  if (UsesVotes(options) && weak()) {
    const size_t first_voted = result.candidates.size();
    {
      ScopedTimer timer(&result.timings.retrieval_ms);
      ScopedTimer votes_timer(&result.timings.votes_ms);
      std::vector<LocalizationCandidate> voted =
          RetrieveByVotes(query, options, result.candidates, evaluation.network_cache);
      result.candidates.insert(result.candidates.end(), voted.begin(), voted.end());
    }
    EvaluateRound(query, options, first_voted, evaluation);
  }
  if (options.retrieval == RetrievalMode::kGlobalThenVotes &&
      options.deeper_global_candidates > 0 && weak() &&
      !LastRoundHoldsDeeperRound(options, global_descriptor, evaluation)) {
    const size_t first_deeper = result.candidates.size();
    {
      ScopedTimer timer(&result.timings.retrieval_ms);
      std::vector<LocalizationCandidate> deeper =
          Retrieve(global_descriptor, options.deeper_global_candidates, result.candidates);
      result.candidates.insert(result.candidates.end(), deeper.begin(), deeper.end());
    }
    if (result.candidates.size() > first_deeper) {
      EvaluateRound(query, options, first_deeper, evaluation);
    }
  }
}

Eigen::VectorXf Localizer::RetrieveFirstRound(const LocalizationQuery& query,
                                              const LocalizerOptions& options,
                                              Evaluation& evaluation) const {
  PoseResult& result = evaluation.result;
  ScopedTimer timer(&result.timings.retrieval_ms);
  if (options.retrieval == RetrievalMode::kVotes) {
    ScopedTimer votes_timer(&result.timings.votes_ms);
    result.candidates = RetrieveByVotes(query, options, {}, evaluation.network_cache);
    return {};
  }
  Eigen::VectorXf global_descriptor;
  if (query.global_descriptor.has_value()) {
    global_descriptor = *query.global_descriptor;
  } else if (query.descriptors.rows() > 0) {
    global_descriptor = map_->vlad()->Encode(query.descriptors, ComputeThreads());
  }
  result.candidates = Retrieve(global_descriptor, options.top_k, {});
  return global_descriptor;
}

PoseResult Localizer::Localize(const LocalizationQuery& query,
                               const LocalizerOptions& options) const {
  if (options.matcher == Matcher::kAuto) {
    LocalizerOptions resolved = options;
    resolved.matcher = auto_matcher_;
    return Localize(query, resolved);
  }
  CheckOptionsFit(options);
  CheckQuery(query);
  if (options.max_matched_keypoints > 0 && query.keypoints.rows() > options.max_matched_keypoints) {
    return LocalizeKeypointSample(query, options);
  }
  const Timer total_timer;
  Evaluation evaluation;
  PoseResult& result = evaluation.result;
  const bool votes_only = options.retrieval == RetrievalMode::kVotes;
  const Eigen::VectorXf global_descriptor = RetrieveFirstRound(query, options, evaluation);
  // A query left without a pose answers with its first candidate's, retrieval's best guess.
  const auto fail = [&](const std::string& reason) {
    if (!result.candidates.empty()) {
      result.cam_from_world =
          map_->scene().images[result.candidates.front().image_index].cam_from_world;
    }
    return Finish(std::move(result), reason, total_timer);
  };
  const int64_t num_keypoints = query.keypoints.rows();
  if (num_keypoints < 4) return fail(fmt::format("the query has {} keypoints", num_keypoints));
  EvaluateRound(query, options, 0, evaluation);
  evaluation.first_round_candidates = result.candidates.size();
  if (!votes_only) EvaluateFurtherRounds(query, options, global_descriptor, evaluation);
  const size_t num_candidates = result.candidates.size();
  if (num_candidates == 0) return fail("retrieval found no database image");
  // Where no round has given a pose, the earlier candidates draw the rest of their budgets in the
  // last round, after its own candidates' first looks, so that a pose it finds bounds them
  // (EvaluateNearestPointRanks). Drawn first, they cost up to 45,000 samples for ten wrong
  // candidates and placed none of the aachen preset's queries that reach the last round (two
  // seeds, docs/decisions.md).
  const bool last_round_follows =
      !votes_only && LastRoundFollows(options, global_descriptor, evaluation);
  if (!last_round_follows) {
    ScopedTimer timer(&result.timings.pose_ms);
    // A better pose found now has not chosen among its rival keypoints yet.
    if (CompleteFirstLooks(query, options, evaluation)) {
      ScopedTimer refine_timer(&result.timings.refine_ms);
      RefineRoundWinner(query, options, 0, evaluation);
    }
  }
  if (!votes_only) EvaluateNearestPointRound(query, options, global_descriptor, evaluation);

  result.best_candidate = Choose(result.candidates);
  if (result.best_candidate < 0) {
    return fail(fmt::format("no candidate pose with at least {} inliers among {} retrieved images",
                            options.pose.min_inliers, num_candidates));
  }
  FinalMatches final;
  {
    ScopedTimer timer(&result.timings.pose_ms);
    ScopedTimer refine_timer(&result.timings.refine_ms);
    final = PoolAgreeingCandidates(query, options, evaluation);
  }
  result.success = true;
  result.cam_from_world = final.cam_from_world;
  result.num_inliers = final.num_inliers;
  result.num_pooled_candidates = final.num_candidates;
  result.match_keypoints = std::move(final.matches.keypoints);
  result.match_points = std::move(final.matches.point_indices);
  result.match_inliers = std::move(final.inlier_mask);
  return Finish(std::move(result), "", total_timer);
}

}  // namespace hscloc
