#include "localization/point_row_matches.h"

#include <gtest/gtest.h>

#include <algorithm>

#include "model/trainer.h"
#include "util/random.h"

namespace hscloc {
namespace {

// 150 points seen by 4 images, each point by two or three of them, its views its own
// random direction plus a little noise: a small map's shape, at a width a test trains in seconds.
Scene SmallMap(int dim) {
  Random random(11);
  Scene scene;
  scene.images.resize(4);
  scene.points.resize(150);
  DescriptorMatrix views(150 * 3, dim);
  int row = 0;
  for (uint32_t point = 0; point < 150; ++point) {
    // Scattered, so that the tree's leaf order is not the points' order.
    scene.points[point] =
        Eigen::Vector3d(random.Uniform(0, 50), random.Uniform(0, 50), random.Uniform(0, 50));
    Eigen::RowVectorXf direction(dim);
    for (int d = 0; d < dim; ++d) direction[d] = static_cast<float>(random.Normal());
    for (uint32_t image = point % 4, seen = 0; seen < 2 + point % 2;
         ++seen, image = (image + 1) % 4) {
      scene.observation_image_indices.push_back(image);
      scene.observation_point_indices.push_back(point);
      views.row(row) = direction;
      for (int d = 0; d < dim; ++d) views(row, d) += 0.05f * static_cast<float>(random.Normal());
      ++row;
    }
  }
  scene.observation_descriptors = views.topRows(row);
  return scene;
}

// The matcher holds each point's own rows: a point's first row, as a query, finds that point
// among any set of points that holds it, and another point where the set does not.
TEST(PointRowMatches, EachPointHoldsItsOwnRows) {
  const int dim = 16;
  const Scene scene = SmallMap(dim);
  LabelTreeOptions tree_options;
  tree_options.show_progress = false;
  const LabelTree tree = LabelTree::Build(scene.points, tree_options);
  TrainerOptions options;
  options.network = DefaultNetworkOptions(scene.NumPoints(), dim);
  options.point_prototypes = kMaxPointPrototypes;
  options.max_iterations = 2;
  options.batch_size = 32;
  // Every view trains, so that every point has rows of its own views.
  options.holdout_fraction = 0;
  options.show_progress = false;
  const Network network = TrainNetwork(scene, tree, options).network;
  // A row per training view.
  ASSERT_EQ(network.shape().point_row_offsets.back(),
            static_cast<int64_t>(scene.NumObservations()));

  const PointRowMatcher matcher(network, tree);
  EXPECT_EQ(matcher.NumPoints(), scene.NumPoints());
  EXPECT_EQ(matcher.NumRows(), static_cast<int64_t>(scene.NumObservations()));
  int64_t width = 0;
  const std::vector<float> table = network.PointRows(&width);
  ASSERT_EQ(width, dim);
  // The table holds point rows by leaf rank; the first row of each point, in point order.
  DescriptorMatrix first_rows(scene.NumPoints(), dim);
  const auto first_leaf = static_cast<uint32_t>(network.shape().FirstNodeOfDepth(tree.levels()));
  for (int64_t rank = 0; rank < static_cast<int64_t>(scene.NumPoints()); ++rank) {
    const auto point = tree.PointOfLeaf(first_leaf + static_cast<uint32_t>(rank));
    const int64_t row = network.shape().point_row_offsets[rank];
    first_rows.row(point) =
        Eigen::Map<const Eigen::RowVectorXf>(table.data() + row * (dim + 1), dim);
  }
  const DescriptorMatrix query = UnitRows(first_rows);
  // The even points, in decreasing order.
  std::vector<uint32_t> subset;
  for (uint32_t point = 0; point < scene.NumPoints(); point += 2) subset.push_back(point);
  std::reverse(subset.begin(), subset.end());
  const CandidateMatches matches = matcher.Match(query, subset, {.ratio = 1.0, .mutual = false});
  ASSERT_EQ(matches.size(), scene.NumPoints());
  for (size_t i = 0; i < matches.size(); ++i) {
    const uint32_t keypoint = static_cast<uint32_t>(matches.keypoints[i]);
    EXPECT_EQ(matches.point_indices[i] % 2, 0u);
    EXPECT_EQ(matches.point_indices[i] == keypoint, keypoint % 2 == 0) << "point " << keypoint;
  }
  EXPECT_THROW(matcher.Match(query, {static_cast<uint32_t>(scene.NumPoints())}, {}),
               std::invalid_argument);
}

TEST(PointRowMatches, ANetworkWithoutPointRowsIsRefused) {
  const Scene scene = SmallMap(8);
  LabelTreeOptions tree_options;
  tree_options.show_progress = false;
  const LabelTree tree = LabelTree::Build(scene.points, tree_options);
  NetworkOptions paper = NetworkOptions::PaperFaithful();
  paper.channels = paper.trunk_channels = 16;
  const Network network(NetworkShape::ForTree(8, tree, 4), paper, 1);
  EXPECT_THROW(PointRowMatcher(network, tree), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
