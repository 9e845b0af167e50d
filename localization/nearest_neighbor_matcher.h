// The explicit-matching baseline: mutual nearest neighbours with Lowe's ratio test between a
// query's descriptors and the observations of one database image (Lowe, IJCV 2004).
#pragma once

#include <cstdint>
#include <vector>

#include "scene/features.h"
#include "scene/scene.h"

namespace hscloc {

// Keypoint -> point matches against one candidate image: query keypoint rows and the dense point
// indices (into Scene::points) they matched, pairwise.
struct CandidateMatches {
  std::vector<int> keypoints;
  std::vector<uint32_t> point_indices;
  // The network's confidence in each match (PointPredictions::confidences); empty for matchers
  // without one.
  std::vector<float> confidences;

  size_t size() const { return keypoints.size(); }
};

struct NearestNeighborOptions {
  // Lowe's ratio on descriptor distances; 1 accepts every best match.
  double ratio = 0.9;
  // Keep a match only when the query keypoint is also the observation's best match.
  bool mutual = true;

  void Check() const;
};

class NearestNeighborMatcher {
 public:
  // Groups the scene's observation descriptors by image, as unit rows, once; the scene may go
  // away afterwards. A scene without observations gives an empty matcher.
  explicit NearestNeighborMatcher(const Scene& scene);

  bool empty() const { return unit_descriptors_.rows() == 0; }
  // The matches of unit query descriptors (UnitRows) against database image `image_index`.
  CandidateMatches Match(const DescriptorMatrix& unit_query, uint32_t image_index,
                         const NearestNeighborOptions& options) const;

 private:
  // Observations of image i are rows [offsets_[i], offsets_[i + 1]).
  std::vector<uint32_t> offsets_;
  DescriptorMatrix unit_descriptors_;
  std::vector<uint32_t> point_indices_;
};

}  // namespace hscloc
