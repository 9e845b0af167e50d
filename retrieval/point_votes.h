// Image retrieval by point votes: every keypoint's predicted map point votes, with a weight, for
// each database image that observes it, and the images are ranked by their summed votes. Where
// a global descriptor (VLAD) of a query is dominated by clutter (at night: fewer detections, more
// spurious ones, noisier descriptors), the few keypoints that do see map points still agree on the
// images that observe those points, while the votes of clutter spread over the whole map.
#pragma once

#include <cstdint>
#include <vector>

#include "map/visibility.h"
#include "retrieval/global_index.h"

namespace hscloc {

class PointVoteIndex {
 public:
  PointVoteIndex() = default;
  // The transpose of the visibility lists: for each point, the images that observe it.
  explicit PointVoteIndex(const Visibility& visibility);

  size_t NumImages() const { return num_images_; }
  size_t NumPoints() const { return offsets_.empty() ? 0 : offsets_.size() - 1; }
  // The images observing a point, ascending, as [begin, end).
  const uint32_t* ImagesBegin(uint32_t point_index) const {
    return image_indices_.data() + offsets_[point_index];
  }
  const uint32_t* ImagesEnd(uint32_t point_index) const {
    return image_indices_.data() + offsets_[point_index + 1];
  }

  // The `top_k` images with the largest sum of the weights of the points they observe, best first
  // (ties: lower image index first); images without a vote are never returned. A negative point
  // index (no prediction) is skipped. Throws std::invalid_argument when the arrays differ in
  // length, a point index is out of range, a weight is negative or not finite, or top_k < 0.
  std::vector<RetrievalHit> Search(const std::vector<int64_t>& points,
                                   const std::vector<float>& weights, int top_k) const;

 private:
  size_t num_images_ = 0;
  std::vector<uint64_t> offsets_;        // per point, into image_indices_
  std::vector<uint32_t> image_indices_;  // 4 bytes per (image, point) pair, as Visibility
};

}  // namespace hscloc
