// The localizer's last round (LocalizerOptions::nearest_point_candidates): where the network has
// left a query without a pose, the global ranking's first images matched against the mean
// descriptors of the points they see (map/point_descriptors.h), and where they give none either,
// the next ones (nearest_point_widened_candidates).
#include <algorithm>
#include <limits>
#include <numeric>

#include "localization/localizer.h"
#include "localization/localizer_evaluation.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {

bool Localizer::UsesNearestPoints(const LocalizerOptions& options) const {
  return options.matcher == Matcher::kNetwork && options.retrieval != RetrievalMode::kVotes &&
         options.nearest_point_candidates > 0 && !map_->point_descriptors().empty();
}

CandidateMatches Localizer::MatchNearestPoints(const DescriptorMatrix& unit_query,
                                               uint32_t image_index,
                                               const LocalizerOptions& options) const {
  const Visibility& visibility = map_->visibility();
  const uint32_t* points = visibility.PointsBegin(image_index);
  const size_t count = visibility.NumPointsOfImage(image_index);
  const DescriptorMatrix rows = map_->point_descriptors().UnitRows(points, count);
  return MatchNearestRows(unit_query, rows, points, options.nearest_neighbor);
}

std::vector<int> Localizer::CountNearestPointMatches(
    const DescriptorMatrix& descriptors, const std::vector<LocalizationCandidate>& images,
    const LocalizerOptions& options) const {
  // Images near one another see many of the same points: their union is matched once, in 8-bit
  // integers (CountNearestRowMatches). The counts are MatchNearestPoints' on the queries at 7 bits
  // but for near ties of similarity; they only rank the images, and the round then matches its
  // chosen images in floats.
  const Visibility& visibility = map_->visibility();
  // Each point's row in the union, by a pass over the map's points rather than a sort of the
  // images' lists and a search for each of their points: on aachen the last round's 200 images
  // see about 200,000 points, several times each.
  constexpr uint32_t kNotSeen = std::numeric_limits<uint32_t>::max();
  std::vector<uint32_t> row_of_point(visibility.NumPoints(), kNotSeen);
  for (const LocalizationCandidate& image : images) {
    const uint32_t* end = visibility.PointsEnd(image.image_index);
    for (const uint32_t* point = visibility.PointsBegin(image.image_index); point != end; ++point) {
      row_of_point[*point] = 0;
    }
  }
  std::vector<uint32_t> points;
  for (size_t point = 0; point < row_of_point.size(); ++point) {
    if (row_of_point[point] == kNotSeen) continue;
    row_of_point[point] = static_cast<uint32_t>(points.size());
    points.push_back(static_cast<uint32_t>(point));
  }
  // An image's points are sorted, and so are their rows, as CountNearestRowMatches asks.
  std::vector<std::vector<uint32_t>> rows_of_images(images.size());
  for (size_t k = 0; k < images.size(); ++k) {
    const uint32_t* end = visibility.PointsEnd(images[k].image_index);
    for (const uint32_t* point = visibility.PointsBegin(images[k].image_index); point != end;
         ++point) {
      rows_of_images[k].push_back(row_of_point[*point]);
    }
  }
  // Read a block at a time: the union of 200 images' points is 50 MB of codes on aachen.
  const PointDescriptors& point_descriptors = map_->point_descriptors();
  return CountNearestRowMatches(
      UnitRows(descriptors), static_cast<int64_t>(points.size()),
      [&](int64_t first, int64_t count) {
        return point_descriptors.CodeRows(points.data() + first, static_cast<size_t>(count));
      },
      rows_of_images, options.nearest_neighbor, ComputeThreads());
}

void Localizer::RankByNearestPointMatches(const DescriptorMatrix& descriptors,
                                          const LocalizerOptions& options,
                                          std::vector<LocalizationCandidate>& images) const {
  const std::vector<int> counts = CountNearestPointMatches(descriptors, images, options);
  for (size_t k = 0; k < images.size(); ++k) images[k].num_matches = counts[k];
  std::stable_sort(images.begin(), images.end(),
                   [](const LocalizationCandidate& a, const LocalizationCandidate& b) {
                     return a.num_matches > b.num_matches;
                   });
}

std::vector<LocalizationCandidate> Localizer::ShortlistForNearestPoints(
    const DescriptorMatrix& descriptors, std::vector<LocalizationCandidate> images,
    const LocalizerOptions& options) const {
  const int64_t sample_size = kNearestPointSampleKeypoints;
  const size_t shortlist = static_cast<size_t>(options.nearest_point_shortlist);
  if (shortlist == 0 || images.size() <= shortlist || descriptors.rows() <= sample_size) {
    return images;
  }
  DescriptorMatrix sample(sample_size, descriptors.cols());
  for (int64_t i = 0; i < sample_size; ++i) {
    sample.row(i) = descriptors.row(i * descriptors.rows() / sample_size);
  }
  const std::vector<int> counts = CountNearestPointMatches(sample, images, options);
  std::vector<size_t> order(images.size());
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return counts[a] > counts[b]; });
  // In the global ranking's order, so that equal full counts rank as without the shortlist.
  order.resize(shortlist);
  std::sort(order.begin(), order.end());
  std::vector<LocalizationCandidate> shortlisted;
  for (const size_t k : order) shortlisted.push_back(images[k]);
  return shortlisted;
}

std::vector<LocalizationCandidate> Localizer::RetrieveByNearestPoints(
    const LocalizationQuery& query, const LocalizerOptions& options,
    const Eigen::VectorXf& global_descriptor, int first_rank, int end_rank) const {
  // Earlier rounds' images are ranked again: the network may have missed its right image.
  std::vector<LocalizationCandidate> images = Retrieve(global_descriptor, end_rank, {});
  images.erase(images.begin(), images.begin() + std::min<size_t>(first_rank, images.size()));
  std::vector<LocalizationCandidate> ranked =
      ShortlistForNearestPoints(query.descriptors, std::move(images), options);
  RankByNearestPointMatches(query.descriptors, options, ranked);
  std::vector<LocalizationCandidate> candidates;
  for (LocalizationCandidate& candidate : ranked) {
    if (static_cast<int>(candidates.size()) == options.top_k ||
        candidate.num_matches < options.pose.min_inliers) {
      break;
    }
    candidate.source = CandidateSource::kNearestPoints;
    candidate.num_matches = 0;  // counted again when the round matches it
    candidates.push_back(candidate);
  }
  return candidates;
}

bool Localizer::LastRoundFollows(const LocalizerOptions& options,
                                 const Eigen::VectorXf& global_descriptor,
                                 const Evaluation& evaluation) const {
  return UsesNearestPoints(options) && global_descriptor.size() > 0 &&
         Choose(evaluation.result.candidates) < 0;
}

bool Localizer::LastRoundHoldsDeeperRound(const LocalizerOptions& options,
                                          const Eigen::VectorXf& global_descriptor,
                                          const Evaluation& evaluation) const {
  // The deeper round's images follow the first round's and the votes' in the global ranking.
  const int deepest_rank = 2 * options.top_k + options.deeper_global_candidates;
  return LastRoundFollows(options, global_descriptor, evaluation) &&
         options.nearest_point_candidates >= deepest_rank;
}

void Localizer::EvaluateNearestPointRound(const LocalizationQuery& query,
                                          const LocalizerOptions& options,
                                          const Eigen::VectorXf& global_descriptor,
                                          Evaluation& evaluation) const {
  if (!LastRoundFollows(options, global_descriptor, evaluation)) return;
  // The global ranking's first images, then, where they give no pose either, the next ones.
  const int num_images = static_cast<int>(map_->scene().NumImages());
  int first_rank = 0;
  int end_rank = options.nearest_point_candidates;
  while (Choose(evaluation.result.candidates) < 0 && first_rank < end_rank &&
         first_rank < num_images) {
    EvaluateNearestPointRanks(query, options, global_descriptor, first_rank, end_rank, evaluation);
    first_rank = end_rank;
    end_rank =
        std::min(options.nearest_point_widened_candidates, end_rank * kNearestPointWideningFactor);
  }
}

void Localizer::EvaluateNearestPointRanks(const LocalizationQuery& query,
                                          const LocalizerOptions& options,
                                          const Eigen::VectorXf& global_descriptor, int first_rank,
                                          int end_rank, Evaluation& evaluation) const {
  PoseResult& result = evaluation.result;
  const size_t first = result.candidates.size();
  {
    ScopedTimer timer(&result.timings.retrieval_ms);
    std::vector<LocalizationCandidate> ranked =
        RetrieveByNearestPoints(query, options, global_descriptor, first_rank, end_rank);
    result.candidates.insert(result.candidates.end(), ranked.begin(), ranked.end());
  }
  if (result.candidates.size() > first) EvaluateRound(query, options, first, evaluation);
  // Every candidate's rest of the budget, the earlier rounds' too (Localize), bounded by the
  // round's pose where it found one.
  ScopedTimer timer(&result.timings.pose_ms);
  if (CompleteFirstLooks(query, options, evaluation)) {
    ScopedTimer refine_timer(&result.timings.refine_ms);
    RefineRoundWinner(query, options, 0, evaluation);
  }
}

}  // namespace hscloc
