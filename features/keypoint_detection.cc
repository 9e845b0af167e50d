#include "features/keypoint_detection.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "util/check.h"

namespace hscloc {
namespace {

constexpr int kCell = 8;
constexpr int kBins = kCell * kCell + 1;

bool IsLocalMaximum(const ScoreMap& scores, int x, int y, int radius_px) {
  const float value = scores(y, x);
  const int x0 = std::max(0, x - radius_px);
  const int x1 = std::min<int>(scores.cols() - 1, x + radius_px);
  const int y0 = std::max(0, y - radius_px);
  const int y1 = std::min<int>(scores.rows() - 1, y + radius_px);
  for (int v = y0; v <= y1; ++v) {
    for (int u = x0; u <= x1; ++u) {
      if (scores(v, u) > value) return false;
    }
  }
  return true;
}

}  // namespace

ScoreMap KeypointHeatmap(const float* logits, int cells_y, int cells_x) {
  const int64_t plane = static_cast<int64_t>(cells_y) * cells_x;
  ScoreMap heatmap(cells_y * kCell, cells_x * kCell);
  float probabilities[kBins];
  for (int cy = 0; cy < cells_y; ++cy) {
    for (int cx = 0; cx < cells_x; ++cx) {
      const float* cell = logits + static_cast<int64_t>(cy) * cells_x + cx;
      float largest = cell[0];
      for (int b = 1; b < kBins; ++b) largest = std::max(largest, cell[b * plane]);
      float sum = 0;
      for (int b = 0; b < kBins; ++b) {
        probabilities[b] = std::exp(cell[b * plane] - largest);
        sum += probabilities[b];
      }
      for (int b = 0; b + 1 < kBins; ++b) {
        heatmap(cy * kCell + b / kCell, cx * kCell + b % kCell) = probabilities[b] / sum;
      }
    }
  }
  return heatmap;
}

std::vector<Peak> NonMaximumSuppression(const ScoreMap& scores, int radius_px, float threshold,
                                        int max_count) {
  THROW_CHECK_MSG(radius_px >= 0 && max_count >= 0, "radius {} px, max_count {}", radius_px,
                  max_count);
  std::vector<Peak> candidates;
  for (int y = 0; y < scores.rows(); ++y) {
    for (int x = 0; x < scores.cols(); ++x) {
      if (scores(y, x) > threshold && IsLocalMaximum(scores, x, y, radius_px)) {
        candidates.push_back({x, y, scores(y, x)});
      }
    }
  }
  // Equal maxima within one window (plateaus) all pass the test above; the first in this order
  // suppresses the others.
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Peak& a, const Peak& b) { return a.score > b.score; });
  std::vector<Peak> kept;
  std::vector<bool> suppressed(scores.size(), false);
  for (const Peak& peak : candidates) {
    if (static_cast<int>(kept.size()) == max_count) break;
    if (suppressed[static_cast<size_t>(peak.y) * scores.cols() + peak.x]) continue;
    kept.push_back(peak);
    for (int v = std::max(0, peak.y - radius_px);
         v <= std::min<int>(scores.rows() - 1, peak.y + radius_px); ++v) {
      for (int u = std::max(0, peak.x - radius_px);
           u <= std::min<int>(scores.cols() - 1, peak.x + radius_px); ++u) {
        suppressed[static_cast<size_t>(v) * scores.cols() + u] = true;
      }
    }
  }
  return kept;
}

DescriptorMatrix SampleDescriptors(const float* map, int dimension, int height, int width,
                                   const KeypointMatrix& points) {
  const int64_t plane = static_cast<int64_t>(height) * width;
  DescriptorMatrix descriptors(points.rows(), dimension);
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    // Cell indices from COLMAP coordinates: cell c spans [c, c + 1), its centre at c + 0.5.
    const float x = std::clamp(points(i, 0) - 0.5f, 0.0f, static_cast<float>(width - 1));
    const float y = std::clamp(points(i, 1) - 0.5f, 0.0f, static_cast<float>(height - 1));
    const int x0 = std::min(static_cast<int>(x), width - 1);
    const int y0 = std::min(static_cast<int>(y), height - 1);
    const int x1 = std::min(x0 + 1, width - 1);
    const int y1 = std::min(y0 + 1, height - 1);
    const float ax = x - x0;
    const float ay = y - y0;
    const float w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay, w11 = ax * ay;
    for (int d = 0; d < dimension; ++d) {
      const float* channel = map + d * plane;
      descriptors(i, d) = w00 * channel[y0 * width + x0] + w01 * channel[y0 * width + x1] +
                          w10 * channel[y1 * width + x0] + w11 * channel[y1 * width + x1];
    }
  }
  NormalizeRows(descriptors);
  return descriptors;
}

Letterbox::Letterbox(int photo_width, int photo_height, int longer_side)
    : photo_width(photo_width), photo_height(photo_height) {
  THROW_CHECK_MSG(photo_width > 0 && photo_height > 0 && longer_side > 0,
                  "photo {} x {}, longer side {}", photo_width, photo_height, longer_side);
  const double scale = static_cast<double>(longer_side) / std::max(photo_width, photo_height);
  scaled_width = std::clamp(static_cast<int>(std::lround(photo_width * scale)), 1, longer_side);
  scaled_height = std::clamp(static_cast<int>(std::lround(photo_height * scale)), 1, longer_side);
}

Eigen::Vector2f Letterbox::ToInput(const Eigen::Vector2f& photo_px) const {
  return {photo_px.x() * scaled_width / photo_width, photo_px.y() * scaled_height / photo_height};
}

Eigen::Vector2f Letterbox::ToPhoto(const Eigen::Vector2f& input_px) const {
  return {input_px.x() * photo_width / scaled_width, input_px.y() * photo_height / scaled_height};
}

std::vector<int> TileOrigins(int length, int tile, int min_overlap, int alignment) {
  THROW_CHECK_MSG(alignment > 0 && tile % alignment == 0 && length % alignment == 0 &&
                      length >= tile && min_overlap >= 0 && min_overlap <= tile - alignment,
                  "length {}, tile {}, overlap {}, alignment {}", length, tile, min_overlap,
                  alignment);
  if (length == tile) return {0};
  // Whole cells, so that an even spread rounded to cells never drifts past the overlap.
  const int stride = (tile - min_overlap) / alignment * alignment;
  const int count = 1 + (length - tile + stride - 1) / stride;
  const int last = (length - tile) / alignment;
  std::vector<int> origins(count);
  for (int i = 0; i < count; ++i) {
    origins[i] = alignment * static_cast<int>(static_cast<int64_t>(last) * i / (count - 1));
  }
  return origins;
}

int NearestTile(const std::vector<int>& origins, int tile, float position) {
  THROW_CHECK(!origins.empty());
  int nearest = 0;
  float best = INFINITY;
  for (int i = 0; i < static_cast<int>(origins.size()); ++i) {
    const float distance = std::abs(position - (origins[i] + 0.5f * tile));
    if (distance < best) {
      best = distance;
      nearest = i;
    }
  }
  return nearest;
}

}  // namespace hscloc
