#include "localization/point_row_matches.h"

#include "util/check.h"

namespace hscloc {

PointRowMatcher::PointRowMatcher(const Network& network, const LabelTree& tree) {
  int64_t dim = 0;
  const std::vector<float> table = network.PointRows(&dim);
  const NetworkShape& shape = network.shape();
  THROW_CHECK_MSG(!table.empty(), "PointRowMatcher: the network has no pooled point rows");
  THROW_CHECK_MSG(shape.FitsTree(tree), "PointRowMatcher: the network does not fit the tree");
  // The table holds a point's rows side by side at its leaf rank (model/point_candidates.h).
  const auto first_leaf = static_cast<uint32_t>(shape.FirstNodeOfDepth(shape.levels));
  const std::vector<int64_t>& rank_offsets = shape.point_row_offsets;
  const auto table_rows = [&](int64_t rank) {
    return rank_offsets.empty()
               ? std::pair<int64_t, int64_t>{rank, rank + 1}
               : std::pair<int64_t, int64_t>{rank_offsets[rank], rank_offsets[rank + 1]};
  };
  const auto num_points = static_cast<int64_t>(tree.NumPoints());
  std::vector<int64_t> rank_of_point(num_points);
  offsets_.assign(num_points + 1, 0);
  for (int64_t rank = 0; rank < num_points; ++rank) {
    const int64_t point = tree.PointOfLeaf(first_leaf + static_cast<uint32_t>(rank));
    rank_of_point[point] = rank;
    const auto [begin, end] = table_rows(rank);
    offsets_[point + 1] = end - begin;
  }
  for (int64_t point = 0; point < num_points; ++point) offsets_[point + 1] += offsets_[point];
  unit_rows_.resize(offsets_.back(), dim);
  for (int64_t point = 0; point < num_points; ++point) {
    const auto [begin, end] = table_rows(rank_of_point[point]);
    for (int64_t row = begin; row < end; ++row) {
      unit_rows_.row(offsets_[point] + row - begin) =
          Eigen::Map<const Eigen::RowVectorXf>(table.data() + row * (dim + 1), dim);
    }
  }
  NormalizeRows(unit_rows_);
}

CandidateMatches PointRowMatcher::Match(const DescriptorMatrix& unit_query,
                                        const std::vector<uint32_t>& points,
                                        const NearestNeighborOptions& options) const {
  int64_t count = 0;
  for (const uint32_t point : points) {
    THROW_CHECK_MSG(point < NumPoints(), "PointRowMatcher: point {} of {}", point, NumPoints());
    count += offsets_[point + 1] - offsets_[point];
  }
  DescriptorMatrix rows(count, unit_rows_.cols());
  std::vector<uint32_t> row_points;
  row_points.reserve(count);
  for (const uint32_t point : points) {
    const int64_t begin = offsets_[point];
    const int64_t size = offsets_[point + 1] - begin;
    rows.middleRows(static_cast<int64_t>(row_points.size()), size) =
        unit_rows_.middleRows(begin, size);
    row_points.insert(row_points.end(), size, point);
  }
  return MatchNearestRows(unit_query, rows, row_points.data(), options);
}

}  // namespace hscloc
