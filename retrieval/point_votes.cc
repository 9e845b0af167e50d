#include "retrieval/point_votes.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "util/check.h"

namespace hscloc {

PointVoteIndex::PointVoteIndex(const Visibility& visibility)
    : num_images_(visibility.NumImages()), offsets_(visibility.NumPoints() + 1, 0) {
  for (uint32_t image = 0; image < num_images_; ++image) {
    for (const uint32_t* p = visibility.PointsBegin(image); p != visibility.PointsEnd(image); ++p) {
      ++offsets_[*p + 1];
    }
  }
  std::partial_sum(offsets_.begin(), offsets_.end(), offsets_.begin());
  image_indices_.resize(offsets_.back());
  // Images are visited in ascending order, so each point's list comes out sorted.
  std::vector<uint64_t> next(offsets_.begin(), offsets_.end() - 1);
  for (uint32_t image = 0; image < num_images_; ++image) {
    for (const uint32_t* p = visibility.PointsBegin(image); p != visibility.PointsEnd(image); ++p) {
      image_indices_[next[*p]++] = image;
    }
  }
}

std::vector<RetrievalHit> PointVoteIndex::Search(const std::vector<int64_t>& points,
                                                 const std::vector<float>& weights,
                                                 int top_k) const {
  THROW_CHECK_MSG(points.size() == weights.size(), "point votes: {} points but {} weights",
                  points.size(), weights.size());
  THROW_CHECK_MSG(top_k >= 0, "point votes: top_k must be >= 0 (got {})", top_k);
  std::vector<float> votes(num_images_, 0.0f);
  for (size_t i = 0; i < points.size(); ++i) {
    const int64_t point = points[i];
    if (point < 0) continue;
    THROW_CHECK_MSG(static_cast<size_t>(point) < NumPoints(),
                    "point votes: point index {} is out of range (the map has {} points)", point,
                    NumPoints());
    THROW_CHECK_MSG(std::isfinite(weights[i]) && weights[i] >= 0,
                    "point votes: weight {} of point {} is negative or not finite", weights[i],
                    point);
    for (const uint32_t* image = ImagesBegin(static_cast<uint32_t>(point));
         image != ImagesEnd(static_cast<uint32_t>(point)); ++image) {
      votes[*image] += weights[i];
    }
  }
  std::vector<uint32_t> voted;
  for (uint32_t image = 0; image < num_images_; ++image) {
    if (votes[image] > 0) voted.push_back(image);
  }
  const size_t k = std::min(voted.size(), static_cast<size_t>(top_k));
  std::partial_sort(voted.begin(), voted.begin() + k, voted.end(), [&](uint32_t a, uint32_t b) {
    return votes[a] != votes[b] ? votes[a] > votes[b] : a < b;
  });
  std::vector<RetrievalHit> hits(k);
  for (size_t i = 0; i < k; ++i) hits[i] = {voted[i], votes[voted[i]]};
  return hits;
}

}  // namespace hscloc
