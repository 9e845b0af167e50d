// Matching the local descriptors of two images: mutual nearest neighbours with a ratio test, on
// unit-normalized descriptors (hloc's nearest_neighbor matcher, mutual_check on).
#pragma once

#include <vector>

#include "scene/colmap_database_writer.h"
#include "scene/features.h"

namespace hscloc {

struct DescriptorMatchingOptions {
  // Lowe's ratio test on L2 distances of unit descriptors, in both directions: a match is kept
  // when its distance is at most this fraction of the second-nearest one. 1 (the default) turns
  // it off, leaving mutual nearest neighbours, as hloc's NN-mutual matcher and XFeat's own: the
  // known poses' epipolar check then removes the wrong matches, and XFeat's 64-D descriptors have
  // close second neighbours, so a ratio test drops most true matches (on Lund 0.9 keeps 222 map
  // points of the 1415 that no ratio test gives; docs/features.md has the measurements).
  double max_ratio = 1.0;
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
