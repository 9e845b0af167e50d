#include "triangulation/pair_selection.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

// Five images; image 5 sees no point. Shared points: (1, 2) 5, (2, 3) 3, (1, 3) 1, (3, 4) 2.
Reconstruction SmallReconstruction() {
  Reconstruction reconstruction;
  for (image_t image_id = 1; image_id <= 5; ++image_id) {
    reconstruction.images[image_id].image_id = image_id;
  }
  point3D_t next_id = 1;
  const auto add_points = [&](std::vector<image_t> image_ids, int count) {
    for (int i = 0; i < count; ++i) {
      Point3D& point = reconstruction.points3D[next_id++];
      for (const image_t image_id : image_ids) point.track.push_back({image_id, 0});
    }
  };
  add_points({1, 2}, 4);
  add_points({1, 2, 3}, 1);
  add_points({2, 3}, 2);
  add_points({3, 4}, 2);
  // Image 4 sees this point twice: it still shares one point with image 1, not two.
  add_points({4, 4, 1}, 1);
  return reconstruction;
}

std::vector<std::pair<image_t, image_t>> Ids(const std::vector<ImagePair>& pairs) {
  std::vector<std::pair<image_t, image_t>> ids;
  for (const ImagePair& pair : pairs) ids.emplace_back(pair.image_id1, pair.image_id2);
  return ids;
}

TEST(PairSelection, KeepsEachImagesMostCovisiblePartners) {
  const Reconstruction reconstruction = SmallReconstruction();
  // Best partners: 1 -> 2, 2 -> 1, 3 -> 2, 4 -> 3; (1, 2) chosen from both sides appears once.
  EXPECT_THAT(Ids(SelectCovisiblePairs(reconstruction, {.pairs_per_image = 1})),
              ElementsAre(std::pair<image_t, image_t>{1, 2}, std::pair<image_t, image_t>{2, 3},
                          std::pair<image_t, image_t>{3, 4}));
  // Second partners: 1 -> 3 and 1 -> 4 tie at one point (the smaller id wins), 2 -> 3, 3 -> 1,
  // 4 -> 1.
  EXPECT_THAT(Ids(SelectCovisiblePairs(reconstruction, {.pairs_per_image = 2})),
              ElementsAre(std::pair<image_t, image_t>{1, 2}, std::pair<image_t, image_t>{1, 3},
                          std::pair<image_t, image_t>{1, 4}, std::pair<image_t, image_t>{2, 3},
                          std::pair<image_t, image_t>{3, 4}));
  // Every co-visible pair, never image 5.
  EXPECT_EQ(SelectCovisiblePairs(reconstruction).size(), 5u);
  EXPECT_TRUE(SelectCovisiblePairs(Reconstruction()).empty());
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { SelectCovisiblePairs(reconstruction, {.pairs_per_image = 0}); }),
              HasSubstr("pairs_per_image"));
}

}  // namespace
}  // namespace hscloc
