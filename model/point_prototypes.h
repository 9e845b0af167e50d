// The rows of pooled point rows (NetworkOptions::pooled_point_rows) and where they start: one row
// per point, or up to a few per point (prototypes) drawn from the point's own training
// observations, so that a point seen from two sides keeps both looks rather than their mean.
// Internal to model/.
#pragma once

#include <torch/torch.h>

#include <cstdint>
#include <vector>

#include "map/label_tree.h"
#include "scene/scene.h"

namespace hscloc {

class PointCandidates;

// NetworkShape::point_row_offsets for up to `max_rows_per_point` rows per point: as many as the
// point has training observations, at least one. Empty for max_rows_per_point <= 1 (one row each).
std::vector<int64_t> PointRowOffsets(const Scene& scene, const std::vector<uint32_t>& training,
                                     const LabelTree& tree, int max_rows_per_point);

// For each training observation (in `training`'s order), the table row it starts: its point's
// only row, its own row when the point has a row per observation, else the row of the nearest of
// the point's prototypes, chosen farthest-first among its observations from the one nearest to
// their mean.
std::vector<int64_t> StartingRowOfObservations(const Scene& scene,
                                               const std::vector<uint32_t>& training,
                                               const PointCandidates& candidates);

// Pooled point rows start from the data: row u is the unit vector along A x summed over the
// training observations x (unit descriptors) that start it (StartingRowOfObservations), A a fixed
// Gaussian projection (r x D), or the identity with the descriptor shortcut (the rows are then
// the points' class means, or their prototypes' means). Every level then starts as a
// nearest-neighbour matcher among the candidates in that projected space and need only learn to
// map a descriptor near A x, a smooth function of it; from random rows it must memorize which row
// is whose, which took far longer than the budget at city scale (docs/decisions.md). Each bias
// starts at -log of its point's rows (Pooling::kBestPoint).
void InitializePointRowsFromDescriptors(const Scene& scene, const std::vector<uint32_t>& training,
                                        const PointCandidates& candidates, bool identity,
                                        torch::Tensor& point_rows);

}  // namespace hscloc
