// Matching the local descriptors of two images: mutual nearest neighbours with a ratio test, on
// unit-normalized descriptors (hloc's nearest_neighbor matcher, mutual_check on).
#pragma once

#include <vector>

#include "scene/colmap_database_writer.h"
#include "scene/features.h"

namespace hscloc {

struct DescriptorMatchingOptions {
  // Lowe's ratio test on L2 distances of unit descriptors, in both directions: a match is kept
  // when its distance is at most this fraction of the second-nearest one. 1 turns it off. 0.9
  // rather than SIFT's usual 0.8: the known poses' epipolar check removes what a looser ratio
  // lets through, and XFeat's 64-D descriptors have closer second neighbours than 128-D SIFT, so
  // 0.8 drops many true matches (docs/features.md has the measurement).
  double max_ratio = 0.9;
  void Check() const;
};

// Mutual nearest neighbours of `descriptors1` and `descriptors2` (one descriptor per row, any
// scale: rows are normalized here; equal dimensions required), each passing the ratio test in its
// own direction. Sorted by point2D_idx1. With fewer than two descriptors on a side the ratio test
// has no second neighbour there and passes.
std::vector<FeatureMatch> MatchDescriptors(const DescriptorMatrix& descriptors1,
                                           const DescriptorMatrix& descriptors2,
                                           const DescriptorMatchingOptions& options = {});

}  // namespace hscloc
