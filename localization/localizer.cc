#include "localization/localizer.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "util/check.h"
#include "util/timer.h"

namespace hscloc {
namespace {

// Keypoint -> point matches of one candidate image.
struct CandidateMatches {
  std::vector<int> keypoints;
  std::vector<uint32_t> points;
};

// Rows scaled to unit L2 norm, so that dot products are cosine similarities.
DescriptorMatrix NormalizedRows(const DescriptorMatrix& rows) {
  DescriptorMatrix normalized = rows;
  for (int64_t i = 0; i < normalized.rows(); ++i) {
    const float norm = normalized.row(i).norm();
    if (norm > 0) normalized.row(i) /= norm;
  }
  return normalized;
}

// Mutual nearest neighbours with Lowe's ratio test between the query's unit descriptors and the
// unit descriptors of one image's observations (whose points are `observation_points`).
CandidateMatches MatchNearestNeighbors(const DescriptorMatrix& query,
                                       const DescriptorMatrix& image_descriptors,
                                       const std::vector<uint32_t>& observation_points,
                                       double ratio, bool mutual) {
  CandidateMatches matches;
  if (query.rows() == 0 || image_descriptors.rows() == 0) return matches;
  const Eigen::MatrixXf similarity = query * image_descriptors.transpose();
  std::vector<int> best_query_of_observation;
  if (mutual) {
    best_query_of_observation.resize(image_descriptors.rows());
    for (int64_t j = 0; j < similarity.cols(); ++j) {
      similarity.col(j).maxCoeff(&best_query_of_observation[j]);
    }
  }
  // For unit vectors, squared distance = 2 - 2 cos.
  const auto distance = [](float cosine) { return std::sqrt(std::max(0.0f, 2 - 2 * cosine)); };
  const double squared_ratio = ratio * ratio;
  for (int64_t i = 0; i < similarity.rows(); ++i) {
    float best = -std::numeric_limits<float>::infinity();
    float second = -std::numeric_limits<float>::infinity();
    int64_t best_j = -1;
    for (int64_t j = 0; j < similarity.cols(); ++j) {
      const float s = similarity(i, j);
      if (s > best) {
        second = best;
        best = s;
        best_j = j;
      } else if (s > second) {
        second = s;
      }
    }
    if (best_j < 0) continue;
    if (std::isfinite(second)) {
      const double d1 = distance(best);
      const double d2 = distance(second);
      if (d1 * d1 >= squared_ratio * d2 * d2) continue;
    }
    if (mutual && best_query_of_observation[best_j] != i) continue;
    matches.keypoints.push_back(static_cast<int>(i));
    matches.points.push_back(observation_points[best_j]);
  }
  return matches;
}

}  // namespace

Matcher ParseMatcher(const std::string& name) {
  if (name == "hsc") return Matcher::kNetwork;
  if (name == "nn") return Matcher::kNearestNeighbor;
  ThrowInvalidArgument("unknown matcher '{}' (hsc, nn)", name);
}

std::string MatcherName(Matcher matcher) { return matcher == Matcher::kNetwork ? "hsc" : "nn"; }

CandidateSearch ParseCandidateSearch(const std::string& name) {
  if (name == "all") return CandidateSearch::kAll;
  if (name == "until-accepted") return CandidateSearch::kUntilAccepted;
  ThrowInvalidArgument("unknown candidate search '{}' (all, until-accepted)", name);
}

std::string CandidateSearchName(CandidateSearch search) {
  return search == CandidateSearch::kAll ? "all" : "until-accepted";
}

void LocalizerOptions::Check() const {
  THROW_CHECK_MSG(top_k >= 1 && top_k <= 1000, "LocalizerOptions.top_k = {} (1 .. 1000)", top_k);
  THROW_CHECK_MSG(accept_candidate_inliers >= 1, "LocalizerOptions.accept_candidate_inliers = {}",
                  accept_candidate_inliers);
  THROW_CHECK_MSG(nn_ratio > 0 && nn_ratio <= 1, "LocalizerOptions.nn_ratio = {}", nn_ratio);
  pose.Check();
}

Localizer::Localizer(std::shared_ptr<const LocalizationMap> map,
                     std::shared_ptr<const Network> network, const LocalizerOptions& options)
    : map_(std::move(map)), network_(std::move(network)), options_(options) {
  THROW_CHECK_MSG(map_ != nullptr, "Localizer: no map");
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
    observation_offsets_.assign(scene.NumImages() + 1, 0);
    for (const uint32_t image : scene.observation_image_indices) ++observation_offsets_[image + 1];
    for (size_t i = 1; i < observation_offsets_.size(); ++i) {
      observation_offsets_[i] += observation_offsets_[i - 1];
    }
    observations_by_image_.resize(scene.NumObservations());
    std::vector<uint32_t> next(observation_offsets_.begin(), observation_offsets_.end() - 1);
    for (uint32_t i = 0; i < scene.NumObservations(); ++i) {
      observations_by_image_[next[scene.observation_image_indices[i]]++] = i;
    }
  }
  CheckOptionsFit(options_);
}

Localizer Localizer::FromBundle(const std::filesystem::path& bundle_dir,
                                const LocalizerOptions& options, ComputeDevice device) {
  auto map = LocalizationMap::Load(
      bundle_dir, {.load_observations = options.matcher == Matcher::kNearestNeighbor,
                   .load_network = options.matcher == Matcher::kNetwork,
                   .device = device});
  std::shared_ptr<const Network> network = map->network();
  return Localizer(std::move(map), std::move(network), options);
}

void Localizer::CheckOptionsFit(const LocalizerOptions& options) const {
  options.Check();
  if (options.matcher == Matcher::kNetwork && network_ == nullptr) {
    ThrowInvalidArgument("{}: the hsc matcher needs a trained network (run `hscloc train`)",
                         map_->dir().string());
  }
  if (options.matcher == Matcher::kNearestNeighbor && observation_offsets_.empty()) {
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

PoseResult Localizer::Localize(const LocalizationQuery& query,
                               const LocalizerOptions& options) const {
  CheckOptionsFit(options);
  CheckQuery(query);
  const Timer total_timer;
  PoseResult result;
  const Scene& scene = map_->scene();
  const int64_t num_keypoints = query.keypoints.rows();

  // 1. Retrieval.
  Timer timer;
  std::vector<RetrievalHit> hits;
  if (query.global_descriptor.has_value() || num_keypoints > 0) {
    const Eigen::VectorXf global = query.global_descriptor.has_value()
                                       ? *query.global_descriptor
                                       : map_->vlad()->Encode(query.descriptors);
    hits = map_->global_index().Search(global, options.top_k);
  }
  for (const RetrievalHit& hit : hits) {
    LocalizationCandidate candidate;
    candidate.image_index = static_cast<uint32_t>(hit.image_index);
    candidate.image_id = scene.images[candidate.image_index].image_id;
    candidate.retrieval_score = hit.score;
    result.candidates.push_back(candidate);
  }
  result.timings.retrieval_ms = timer.ElapsedMilliseconds();
  if (!result.candidates.empty()) {
    result.cam_from_world = scene.images[result.candidates.front().image_index].cam_from_world;
  }
  const auto finish = [&](std::string failure_reason) {
    result.failure_reason = std::move(failure_reason);
    result.timings.total_ms = total_timer.ElapsedMilliseconds();
    return result;
  };
  if (num_keypoints < 4) return finish(fmt::format("the query has {} keypoints", num_keypoints));
  if (result.candidates.empty()) return finish("retrieval found no database image");

  const DescriptorMatrix unit_query = options.matcher == Matcher::kNearestNeighbor
                                          ? NormalizedRows(query.descriptors)
                                          : DescriptorMatrix();
  // The matches of candidates [begin, end), from the network (batched) or nearest neighbours.
  std::vector<CandidateMatches> matches(result.candidates.size());
  const auto match_candidates = [&](size_t begin, size_t end) {
    Timer stage_timer;
    if (options.matcher == Matcher::kNetwork) {
      std::vector<uint32_t> images;
      if (options.use_image_id) {
        for (size_t k = begin; k < end; ++k) images.push_back(result.candidates[k].image_index);
      } else {
        images.push_back(network_->NoImageIndex());
      }
      const PointPredictions predictions =
          network_->Predict(query.descriptors, images, map_->label_tree(),
                            options.visibility_masked_decoding ? &map_->visibility() : nullptr);
      for (size_t k = begin; k < end; ++k) {
        const int64_t row = options.use_image_id ? static_cast<int64_t>(k - begin) : 0;
        for (int64_t n = 0; n < num_keypoints; ++n) {
          const int64_t point = predictions.point_indices(row, n);
          if (point < 0) continue;
          matches[k].keypoints.push_back(static_cast<int>(n));
          matches[k].points.push_back(static_cast<uint32_t>(point));
        }
      }
    } else {
      for (size_t k = begin; k < end; ++k) {
        const uint32_t image = result.candidates[k].image_index;
        const uint32_t first = observation_offsets_[image];
        const uint32_t count = observation_offsets_[image + 1] - first;
        DescriptorMatrix image_descriptors(count, scene.Dimension());
        std::vector<uint32_t> points(count);
        for (uint32_t i = 0; i < count; ++i) {
          const uint32_t observation = observations_by_image_[first + i];
          image_descriptors.row(i) = scene.observation_descriptors.row(observation);
          points[i] = scene.observation_point_indices[observation];
        }
        matches[k] = MatchNearestNeighbors(unit_query, NormalizedRows(image_descriptors), points,
                                           options.nn_ratio, options.nn_mutual);
      }
    }
    result.timings.match_ms += stage_timer.ElapsedMilliseconds();
    stage_timer.Restart();
    for (size_t k = begin; k < end; ++k) {
      if (options.visibility_filter) {
        CandidateMatches& candidate = matches[k];
        size_t kept = 0;
        for (size_t i = 0; i < candidate.points.size(); ++i) {
          if (map_->visibility().IsVisible(result.candidates[k].image_index, candidate.points[i])) {
            candidate.keypoints[kept] = candidate.keypoints[i];
            candidate.points[kept] = candidate.points[i];
            ++kept;
          }
        }
        candidate.keypoints.resize(kept);
        candidate.points.resize(kept);
      }
      result.candidates[k].num_matches = static_cast<int>(matches[k].points.size());
    }
    result.timings.visibility_ms += stage_timer.ElapsedMilliseconds();
  };

  std::vector<char> best_inlier_mask;
  const auto estimate_pose = [&](size_t k) {
    Timer stage_timer;
    LocalizationCandidate& candidate = result.candidates[k];
    candidate.evaluated = true;
    const CandidateMatches& candidate_matches = matches[k];
    std::vector<Eigen::Vector2d> keypoints;
    std::vector<Eigen::Vector3d> points;
    for (size_t i = 0; i < candidate_matches.points.size(); ++i) {
      keypoints.push_back(
          query.keypoints.row(candidate_matches.keypoints[i]).transpose().cast<double>());
      points.push_back(scene.points[candidate_matches.points[i]]);
    }
    const AbsolutePoseResult pose =
        EstimateAbsolutePose(query.camera, keypoints, points, options.pose);
    candidate.pose_found = pose.success;
    candidate.num_inliers = pose.success ? pose.num_inliers : 0;
    candidate.cam_from_world = pose.cam_from_world;
    if (pose.success &&
        (result.best_candidate < 0 ||
         candidate.num_inliers > result.candidates[result.best_candidate].num_inliers)) {
      result.best_candidate = static_cast<int>(k);
      best_inlier_mask = pose.inlier_mask;
    }
    result.timings.pose_ms += stage_timer.ElapsedMilliseconds();
  };

  const size_t num_candidates = result.candidates.size();
  if (options.candidate_search == CandidateSearch::kAll) {
    match_candidates(0, num_candidates);
    for (size_t k = 0; k < num_candidates; ++k) estimate_pose(k);
  } else {
    // The first candidate alone: when retrieval is right it settles the query, and the network
    // runs on one image id instead of K. The rest follow as one batch only when it does not.
    match_candidates(0, 1);
    estimate_pose(0);
    if (result.candidates[0].num_inliers < options.accept_candidate_inliers && num_candidates > 1) {
      match_candidates(1, num_candidates);
      for (size_t k = 1; k < num_candidates; ++k) {
        estimate_pose(k);
        if (result.candidates[k].num_inliers >= options.accept_candidate_inliers) break;
      }
    }
  }

  if (result.best_candidate < 0) {
    return finish(
        fmt::format("no candidate pose with at least {} inliers among {} retrieved images",
                    options.pose.min_inliers, num_candidates));
  }
  const LocalizationCandidate& best = result.candidates[result.best_candidate];
  result.success = true;
  result.cam_from_world = best.cam_from_world;
  result.num_inliers = best.num_inliers;
  result.match_keypoints = matches[result.best_candidate].keypoints;
  result.match_points = matches[result.best_candidate].points;
  result.match_inliers = std::move(best_inlier_mask);
  return finish("");
}

}  // namespace hscloc
