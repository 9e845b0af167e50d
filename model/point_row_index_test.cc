#include "model/point_row_index.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <numeric>
#include <set>

#include "model/network_test_support.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using testing_support::MakeRandomMap;
using testing_support::RandomDescriptors;
using testing_support::RandomMap;

NetworkOptions PooledOptions() {
  NetworkOptions options = testing_support::SmallOptions();
  options.node_output_dim = 8;
  options.pooled_point_rows = true;
  options.shared_trunk = true;
  return options;
}

// Point rows drawn at random (an untrained network's start at zero ties every point).
Network WithRandomPointRows(Network network, uint64_t seed) {
  torch::NoGradGuard no_grad;
  torch::manual_seed(seed);
  NetworkInternals::Module(network)->point_rows.normal_(0, 1);
  return testing_support::WithRandomProjections(std::move(network), seed + 1);
}

double TotalFlops(const PointPredictions& predictions) {
  return std::accumulate(predictions.level_flops.begin(), predictions.level_flops.end(), 0.0);
}

// Every point sits in exactly one list, with its own row, in segments of its first-level label.
TEST(PointRowIndexTest, ListsPartitionThePointsWithTheirRowsAndLabels) {
  const RandomMap map = MakeRandomMap(3);
  Network network = WithRandomPointRows(Network(map.shape, PooledOptions(), 1), 2);
  const PointRowIndex index = PointRowIndex::Build(network, map.tree);
  const torch::Tensor table = NetworkInternals::Module(network)->point_rows;
  const int64_t points = table.size(0);
  ASSERT_EQ(index.NumPoints(), points);
  EXPECT_EQ(index.RowWidth(), table.size(1));
  EXPECT_EQ(index.NumLists(), std::llround(std::sqrt(static_cast<double>(points))));
  std::set<uint32_t> seen;
  const uint32_t first_leaf = static_cast<uint32_t>(map.shape.FirstNodeOfDepth(map.tree.levels()));
  for (int64_t list = 0; list < index.NumLists(); ++list) {
    const PointRowIndex::Segments segments = index.SegmentsOf(list);
    const int64_t size = index.ListEnd(list) - index.ListBegin(list);
    ASSERT_EQ(segments.starts[segments.count], size);
    for (int64_t k = 0; k < segments.count; ++k) {
      for (uint32_t m = segments.starts[k]; m < segments.starts[k + 1]; ++m) {
        const uint32_t rank = index.Ranks()[index.ListBegin(list) + m];
        EXPECT_TRUE(seen.insert(rank).second) << "rank " << rank << " twice";
        const uint32_t point = static_cast<uint32_t>(map.tree.PointOfLeaf(first_leaf + rank));
        EXPECT_EQ(map.tree.LabelsOfPoint(point)[0], segments.labels[k]);
        for (int64_t d = 0; d < index.RowWidth(); ++d) {
          ASSERT_EQ(index.Rows(list)[m * index.RowWidth() + d], table[rank][d].item<float>());
        }
      }
    }
  }
  EXPECT_EQ(static_cast<int64_t>(seen.size()), points);
}

// Probing every list scores every point: the predictions are those without the index, bit for
// bit; probing a few does less work and still gives every row a label path in the tree.
TEST(PointRowIndexTest, ProbingEveryListIsExactAndFewerListsAreCheaper) {
  const RandomMap map = MakeRandomMap(4);
  const Network network = WithRandomPointRows(Network(map.shape, PooledOptions(), 3), 4);
  const DescriptorMatrix descriptors = RandomDescriptors(200, map.shape.descriptor_dim, 5);
  const std::vector<uint32_t> no_image = {network.NoImageIndex()};
  const PointPredictions exact = network.Predict(descriptors, no_image, map.tree);

  PointRowIndexOptions options;
  options.lists = 20;
  options.probes = 20;
  const PointRowIndex every_list = PointRowIndex::Build(network, map.tree, options);
  const PointPredictions probed_all =
      network.Predict(descriptors, no_image, map.tree, nullptr, nullptr, &every_list);
  EXPECT_EQ(probed_all.labels, exact.labels);
  EXPECT_EQ(probed_all.confidences, exact.confidences);

  options.probes = 3;
  const PointRowIndex few_lists = PointRowIndex::Build(network, map.tree, options);
  const PointPredictions probed_few =
      network.Predict(descriptors, no_image, map.tree, nullptr, nullptr, &few_lists);
  EXPECT_LT(TotalFlops(probed_few), TotalFlops(exact));
  EXPECT_TRUE((probed_few.point_indices.array() >= 0).all());
  EXPECT_TRUE((probed_few.confidences.array() > 0).all());
  // The best list's points are scored: most rows keep the exact first-level label.
  int64_t same_first_label = 0;
  for (int64_t row = 0; row < exact.labels.rows(); ++row) {
    same_first_label += probed_few.labels(row, 0) == exact.labels(row, 0);
  }
  EXPECT_GE(same_first_label, exact.labels.rows() / 2);
}

// Rows conditioned on an image never use the index: their candidates are the image's points.
TEST(PointRowIndexTest, ImageRowsIgnoreTheIndex) {
  const RandomMap map = MakeRandomMap(5);
  const Network network = WithRandomPointRows(Network(map.shape, PooledOptions(), 6), 7);
  PointRowIndexOptions options;
  options.probes = 1;
  const PointRowIndex index = PointRowIndex::Build(network, map.tree, options);
  const DescriptorMatrix descriptors = RandomDescriptors(100, map.shape.descriptor_dim, 8);
  for (const Visibility* mask : {static_cast<const Visibility*>(nullptr), &map.visibility}) {
    const PointPredictions plain = network.Predict(descriptors, {0, 4}, map.tree, mask);
    const PointPredictions indexed =
        network.Predict(descriptors, {0, 4}, map.tree, mask, nullptr, &index);
    EXPECT_EQ(indexed.labels, plain.labels);
    EXPECT_EQ(indexed.confidences, plain.confidences);
  }
}

// The rows without an image are pooled all at once, their lists split among the threads: the
// predictions do not depend on the thread count, and beside image rows in the same call both
// kinds get what they get alone.
TEST(PointRowIndexTest, IndexedRowsDoNotDependOnThreadsOrTheOtherRows) {
  const RandomMap map = MakeRandomMap(6);
  const Network network = WithRandomPointRows(Network(map.shape, PooledOptions(), 9), 10);
  PointRowIndexOptions options;
  options.lists = 24;
  options.probes = 4;
  const PointRowIndex index = PointRowIndex::Build(network, map.tree, options);
  // More rows than one block of the CPU pass holds.
  const DescriptorMatrix descriptors = RandomDescriptors(300, map.shape.descriptor_dim, 11);
  const std::vector<uint32_t> no_image = {network.NoImageIndex()};
  SetComputeThreads(1);
  const PointPredictions one_thread =
      network.Predict(descriptors, no_image, map.tree, nullptr, nullptr, &index);
  SetComputeThreads(3);
  const PointPredictions three_threads =
      network.Predict(descriptors, no_image, map.tree, nullptr, nullptr, &index);
  const PointPredictions image_alone =
      network.Predict(descriptors, {2}, map.tree, nullptr, nullptr, &index);
  const PointPredictions mixed =
      network.Predict(descriptors, {2, network.NoImageIndex()}, map.tree, nullptr, nullptr, &index);
  SetComputeThreads(0);
  EXPECT_EQ(three_threads.labels, one_thread.labels);
  EXPECT_EQ(three_threads.confidences, one_thread.confidences);
  const int64_t n = descriptors.rows();
  EXPECT_EQ(mixed.labels.topRows(n), image_alone.labels);
  EXPECT_EQ(mixed.labels.bottomRows(n), one_thread.labels);
  EXPECT_EQ(mixed.confidences.row(0), image_alone.confidences.row(0));
  EXPECT_EQ(mixed.confidences.row(1), one_thread.confidences.row(0));
}

TEST(PointRowIndexTest, RefusesWhatDoesNotFit) {
  const RandomMap map = MakeRandomMap(6);
  NetworkOptions node_rows = PooledOptions();
  node_rows.pooled_point_rows = false;
  try {
    PointRowIndex::Build(Network(map.shape, node_rows, 1), map.tree);
    FAIL() << "an index over a network without point rows";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("no pooled point rows"));
  }
  PointRowIndexOptions options;
  options.probes = 0;
  EXPECT_THROW(PointRowIndex::Build(Network(map.shape, PooledOptions(), 1), map.tree, options),
               std::invalid_argument);
  // An index of another map's points.
  const LabelTree small_tree = testing_support::SixtyPointTree();
  const PointRowIndex foreign = PointRowIndex::Build(
      Network(NetworkShape::ForTree(24, small_tree, 4), PooledOptions(), 1), small_tree);
  ASSERT_EQ(foreign.NumPoints(), 60);
  const Network network(map.shape, PooledOptions(), 1);
  try {
    network.Predict(RandomDescriptors(5, map.shape.descriptor_dim, 1), {network.NoImageIndex()},
                    map.tree, nullptr, nullptr, &foreign);
    FAIL() << "an index of another map's points";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("point row index of 60 rows"));
  }
}

}  // namespace
}  // namespace hscloc
