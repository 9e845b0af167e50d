// The steps of a SuperPoint-style detector that are not in the network's graph (DeTone et al.,
// "SuperPoint: Self-Supervised Interest Point Detection and Description", CVPRW 2018): the
// keypoint heatmap from cell logits, non-maximum suppression, and descriptor sampling from a
// coarse dense map. Coordinates follow COLMAP: the centre of the top-left pixel is (0.5, 0.5).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "scene/features.h"

namespace hscloc {

using ScoreMap = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// Cell logits (65 x cells_y x cells_x, channel-major: 64 positions of an 8 x 8 cell in row-major
// order, then a "no keypoint" bin) -> the per-pixel keypoint probability (8 cells_y x 8 cells_x):
// a softmax over the 65 bins of each cell, the last bin dropped.
ScoreMap KeypointHeatmap(const float* logits, int cells_y, int cells_x);

struct Peak {
  int x = 0;  // column
  int y = 0;  // row
  float score = 0;
};

// The pixels of `scores` above `threshold` that are the largest within `radius_px` (a square
// window, as SuperPoint's max-pooling), best first, at most `max_count`. Of two kept pixels, one is
// more than radius_px from the other in x or y; ties are broken by position (row-major), so the
// result is deterministic.
std::vector<Peak> NonMaximumSuppression(const ScoreMap& scores, int radius_px, float threshold,
                                        int max_count);

// Bilinear samples of a dense descriptor map (dimension x height x width, channel-major) at
// `points` given in map cells (COLMAP convention: the centre of cell (0, 0) is (0.5, 0.5); samples
// beyond the outer cell centres take the border value), each L2-normalized: one row per point.
DescriptorMatrix SampleDescriptors(const float* map, int dimension, int height, int width,
                                   const KeypointMatrix& points);

// Where a photo lands when scaled, its aspect kept, so that its longer side is `longer_side` (into
// the top-left corner of a network input, the rest padded). Each axis has its own exact factor
// (the scaled size is rounded to whole pixels), and the mapping is that of an image resize with
// pixel centres aligned (cv::resize).
struct Letterbox {
  Letterbox(int photo_width, int photo_height, int longer_side);
  int photo_width;
  int photo_height;
  int scaled_width;
  int scaled_height;
  Eigen::Vector2f ToInput(const Eigen::Vector2f& photo_px) const;
  Eigen::Vector2f ToPhoto(const Eigen::Vector2f& input_px) const;
};

// Tiles of side `tile` that cover [0, length) for a network with a fixed input: the fewest whose
// neighbours overlap by at least `min_overlap`, spread evenly, each origin a multiple of
// `alignment` (the network's cell), the last ending at `length`. `length` must be a multiple of
// `alignment` and at least `tile`; one tile when it equals `tile`.
std::vector<int> TileOrigins(int length, int tile, int min_overlap, int alignment);

// Of the tiles at `origins` (side `tile`), the one whose centre is nearest to `position`: each
// position takes the network's output from the tile that gives it the most context.
int NearestTile(const std::vector<int>& origins, int tile, float position);

}  // namespace hscloc
