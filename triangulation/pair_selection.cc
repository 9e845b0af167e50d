#include "triangulation/pair_selection.h"

#include <algorithm>
#include <map>
#include <set>

#include "util/check.h"

namespace hscloc {

void PairSelectionOptions::Check() const {
  THROW_CHECK_MSG(pairs_per_image > 0, "pairs_per_image must be positive, not {}", pairs_per_image);
}

std::vector<ImagePair> SelectCovisiblePairs(const Reconstruction& reconstruction,
                                            const PairSelectionOptions& options) {
  options.Check();
  // image -> (other image -> 3D points both observe)
  std::map<image_t, std::map<image_t, int>> shared_points;
  for (const auto& [point3D_id, point] : reconstruction.points3D) {
    // An image seeing a point twice (two 2D points in one track) counts it once, as in hloc.
    std::set<image_t> images;
    for (const TrackElement& element : point.track) images.insert(element.image_id);
    for (const image_t image_id : images) {
      for (const image_t other : images) {
        if (other != image_id) ++shared_points[image_id][other];
      }
    }
  }
  std::set<ImagePair> pairs;
  for (const auto& [image_id, counts] : shared_points) {
    std::vector<std::pair<int, image_t>> partners;
    for (const auto& [other, count] : counts) partners.emplace_back(count, other);
    const size_t kept = std::min<size_t>(options.pairs_per_image, partners.size());
    std::partial_sort(partners.begin(), partners.begin() + kept, partners.end(),
                      [](const auto& a, const auto& b) {
                        return a.first > b.first || (a.first == b.first && a.second < b.second);
                      });
    for (size_t i = 0; i < kept; ++i) {
      const image_t other = partners[i].second;
      pairs.insert({std::min(image_id, other), std::max(image_id, other)});
    }
  }
  return {pairs.begin(), pairs.end()};
}

}  // namespace hscloc
