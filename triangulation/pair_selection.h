// Image pairs to match for triangulating a map from known poses: the co-visibility pairs of an
// existing reconstruction, as hloc's pairs_from_covisibility chooses them.
#pragma once

#include <vector>

#include "scene/reconstruction.h"
#include "util/types.h"

namespace hscloc {

struct ImagePair {
  image_t image_id1 = kInvalidImageId;  // the smaller id
  image_t image_id2 = kInvalidImageId;
  bool operator==(const ImagePair& other) const {
    return image_id1 == other.image_id1 && image_id2 == other.image_id2;
  }
  bool operator<(const ImagePair& other) const {
    return image_id1 < other.image_id1 ||
           (image_id1 == other.image_id1 && image_id2 < other.image_id2);
  }
};

struct PairSelectionOptions {
  // Partners per image: the images that share the most 3D points with it (hloc's default: 20).
  int pairs_per_image = 20;
  void Check() const;
};

// For every image of `reconstruction`, the `pairs_per_image` other images that observe the most
// of its 3D points (ties broken by the smaller image id; images sharing none are never paired),
// as pairs with the smaller id first, deduplicated and sorted. A reconstruction without 3D points
// yields no pair.
std::vector<ImagePair> SelectCovisiblePairs(const Reconstruction& reconstruction,
                                            const PairSelectionOptions& options = {});

}  // namespace hscloc
