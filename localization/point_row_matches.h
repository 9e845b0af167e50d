// Nearest-neighbour matching against a network's own point rows, for the final pose. A network
// with several rows per point (TrainerOptions::point_prototypes) keeps, on a small map, a row per
// training view of each point: what nearest-neighbour matching keeps, at 8 bits. Its decoding keeps
// each point's most confident keypoint, and on real photos those matches leave a pose freer than
// mutual nearest neighbours with a ratio test do (docs/decisions.md, "The network on real
// photos"). So once the network has chosen the winner, it is matched again against the rows of
// the points its image sees, with those two filters, and posed anew from those matches; the
// candidates that agree with that pose are matched the same way, and the final pose is refined
// over all of their matches.
#pragma once

#include <vector>

#include "localization/nearest_neighbor_matcher.h"
#include "map/label_tree.h"
#include "model/network.h"

namespace hscloc {

class PointRowMatcher {
 public:
  // The rows (weights without the bias, as unit rows) of `network`'s pooled point table, by point
  // of `tree` (the tree the network was trained on). Throws std::invalid_argument when the network
  // has no pooled point rows or does not fit the tree.
  PointRowMatcher(const Network& network, const LabelTree& tree);

  size_t NumPoints() const { return offsets_.size() - 1; }
  int64_t NumRows() const { return unit_rows_.rows(); }
  // MatchNearestRows between unit query rows and the rows of `points` (dense point indices, each
  // once, any order; throws std::invalid_argument for an index past the map's points).
  CandidateMatches Match(const DescriptorMatrix& unit_query, const std::vector<uint32_t>& points,
                         const NearestNeighborOptions& options) const;

 private:
  // Point p's rows are [offsets_[p], offsets_[p + 1]) of unit_rows_.
  std::vector<int64_t> offsets_;
  DescriptorMatrix unit_rows_;
};

}  // namespace hscloc
