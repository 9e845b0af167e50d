#include "model/network.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <numeric>
#include <sstream>

#include "model/network_module.h"
#include "model/network_test_support.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using testing_support::MakeRandomMap;
using testing_support::RandomDescriptors;
using testing_support::RandomMap;
using testing_support::SmallOptions;

TEST(NetworkOptionsTest, ChecksNameTheField) {
  NetworkOptions options;
  EXPECT_NO_THROW(options.Check());
  options.conditioned_layers = 4;
  EXPECT_THROW(
      try { options.Check(); } catch (const std::invalid_argument& error) {
        EXPECT_THAT(error.what(), HasSubstr("conditioned_layers"));
        throw;
      },
      std::invalid_argument);
  options = NetworkOptions();
  options.channels = 0;
  EXPECT_THROW(options.Check(), std::invalid_argument);
  NetworkShape shape;
  shape.descriptor_dim = 64;
  shape.levels = 4;
  shape.branching = 257;
  shape.num_images = 10;
  EXPECT_THROW(shape.Check(), std::invalid_argument);
  shape.branching = 100;
  EXPECT_NO_THROW(shape.Check());
  shape.num_images = 0;
  EXPECT_THROW(shape.Check(), std::invalid_argument);
  EXPECT_EQ(ParseComputeDevice("cpu"), ComputeDevice::kCpu);
  EXPECT_THROW(ParseComputeDevice("tpu"), std::invalid_argument);
  options = NetworkOptions();
  options.node_output_dim = -1;
  EXPECT_THROW(
      try { options.Check(); } catch (const std::invalid_argument& error) {
        EXPECT_THAT(error.what(), HasSubstr("node_output_dim"));
        throw;
      },
      std::invalid_argument);
  shape = NetworkShape{64, 4, 100, 10, {1, 100, 200}, {}};  // 3 depths for 4 levels
  EXPECT_THROW(
      try { shape.Check(); } catch (const std::invalid_argument& error) {
        EXPECT_THAT(error.what(), HasSubstr("nodes_per_depth"));
        throw;
      },
      std::invalid_argument);
}

TEST(NetworkOptionsTest, DescriptorShortcutNeedsPooledRowsAtTheDescriptorsWidth) {
  const RandomMap map = MakeRandomMap(1);
  NetworkOptions options = SmallOptions();
  options.descriptor_shortcut = true;
  options.node_output_dim = map.shape.descriptor_dim;
  EXPECT_THROW(
      try { options.Check(); } catch (const std::invalid_argument& error) {
        EXPECT_THAT(error.what(), HasSubstr("descriptor_shortcut needs pooled_point_rows"));
        throw;
      },
      std::invalid_argument);
  options.pooled_point_rows = true;
  EXPECT_NO_THROW(Network(map.shape, options, 1));
  options.node_output_dim = 8;
  EXPECT_THROW(
      try { Network(map.shape, options, 1); } catch (const std::invalid_argument& error) {
        EXPECT_THAT(error.what(), HasSubstr("equal to the descriptor dimension (24)"));
        throw;
      },
      std::invalid_argument);
}

TEST(NetworkOptionsTest, PerNodeTablesNeedTheTreesNodeCounts) {
  const RandomMap map = MakeRandomMap(1);
  NetworkShape without_counts = map.shape;
  without_counts.nodes_per_depth.clear();
  EXPECT_NO_THROW(Network(without_counts, NetworkOptions::PaperFaithful(), 1));
  for (const NetworkOptions& options :
       testing_support::HeadVariants(SmallOptions(), map.shape.descriptor_dim)) {
    if (!options.NeedsNodeCounts()) continue;
    EXPECT_THROW(
        try { Network(without_counts, options, 1); } catch (const std::invalid_argument& error) {
          EXPECT_THAT(error.what(), HasSubstr("nodes_per_depth"));
          throw;
        },
        std::invalid_argument);
  }
  // Counts of another tree are refused at prediction time.
  const RandomMap other = MakeRandomMap(2);
  const Network network(map.shape, SmallOptions(), 1);
  if (!(other.shape == map.shape)) {
    EXPECT_THROW(network.Predict(RandomDescriptors(3, 24, 1), {0}, other.tree),
                 std::invalid_argument);
  }
  // The paper's configuration has no per-node table; node rows grow with the tree's nodes.
  const Network paper(map.shape, NetworkOptions::PaperFaithful(), 1);
  NetworkOptions rows = NetworkOptions::PaperFaithful();
  rows.node_output_dim = 8;
  const Network with_rows(map.shape, rows, 1);
  EXPECT_GT(with_rows.NumParameters(), paper.NumParameters());
}

TEST(NetworkTest, PredictionsAreConsistentWithTheTree) {
  const RandomMap map = MakeRandomMap(1);
  const Network network(map.shape, SmallOptions(), 7);
  EXPECT_EQ(network.NoImageIndex(), 9u);
  const DescriptorMatrix descriptors = RandomDescriptors(40, map.shape.descriptor_dim, 2);
  const std::vector<uint32_t> images = {0, 4, network.NoImageIndex()};
  const PointPredictions predictions = network.Predict(descriptors, images, map.tree);
  ASSERT_EQ(predictions.num_images, 3);
  ASSERT_EQ(predictions.num_descriptors, 40);
  ASSERT_EQ(predictions.labels.rows(), 120);
  ASSERT_EQ(predictions.labels.cols(), 3);
  for (int64_t k = 0; k < 3; ++k) {
    for (int64_t n = 0; n < 40; ++n) {
      const uint8_t* labels = predictions.labels.data() + (k * 40 + n) * 3;
      EXPECT_EQ(predictions.point_indices(k, n), map.tree.PointOfLabels(labels));
      EXPECT_GT(predictions.confidences(k, n), 0.0f);
      EXPECT_LE(predictions.confidences(k, n), 1.0f);
      for (int level = 0; level < 3; ++level) EXPECT_LT(labels[level], 12);
    }
  }
  // The image conditions the prediction: an untrained network already answers differently.
  EXPECT_NE(predictions.labels.topRows(40), predictions.labels.middleRows(40, 40));

  const PointPredictions empty = network.Predict(DescriptorMatrix(0, 24), images, map.tree);
  EXPECT_EQ(empty.point_indices.size(), 0);
}

TEST(NetworkTest, BatchedImagesEqualSeparateCalls) {
  const RandomMap map = MakeRandomMap(2);
  const Network network(map.shape, SmallOptions(), 3);
  const DescriptorMatrix descriptors = RandomDescriptors(200, map.shape.descriptor_dim, 4);
  const std::vector<uint32_t> images = {3, 1, 3, 8, network.NoImageIndex(), 0};
  for (const Visibility* mask : {static_cast<const Visibility*>(nullptr), &map.visibility}) {
    const PointPredictions batched = network.Predict(descriptors, images, map.tree, mask);
    for (size_t k = 0; k < images.size(); ++k) {
      const PointPredictions single = network.Predict(descriptors, {images[k]}, map.tree, mask);
      EXPECT_EQ(batched.point_indices.row(k), single.point_indices.row(0)) << "image " << k;
      EXPECT_EQ(batched.labels.middleRows(k * 200, 200), single.labels) << "image " << k;
      EXPECT_TRUE(batched.confidences.row(k).isApprox(single.confidences.row(0), 1e-5f))
          << "image " << k;
    }
  }
}

TEST(NetworkTest, VisibilityMaskKeepsPredictionsInTheImage) {
  const RandomMap map = MakeRandomMap(3);
  for (const bool pooled : {false, true}) {
    SCOPED_TRACE(testing::Message() << "pooled point rows " << pooled);
    NetworkOptions options = SmallOptions();
    options.pooled_point_rows = pooled;
    const Network network(map.shape, options, 5);
    const DescriptorMatrix descriptors = RandomDescriptors(300, map.shape.descriptor_dim, 6);
    const std::vector<uint32_t> images = {0, 2, 5, 7};
    const PointPredictions plain = network.Predict(descriptors, images, map.tree);
    const PointPredictions masked = network.Predict(descriptors, images, map.tree, &map.visibility);
    size_t plain_visible = 0;
    for (size_t k = 0; k < images.size(); ++k) {
      for (int64_t n = 0; n < 300; ++n) {
        const int64_t point = masked.point_indices(k, n);
        ASSERT_GE(point, 0);
        EXPECT_TRUE(map.visibility.IsVisible(images[k], static_cast<uint32_t>(point)));
        EXPECT_LE(masked.confidences(k, n), 1.0f);
        const int64_t plain_point = plain.point_indices(k, n);
        plain_visible += plain_point >= 0 &&
                         map.visibility.IsVisible(images[k], static_cast<uint32_t>(plain_point));
      }
    }
    // Without the mask an untrained network lands mostly on points the image does not see.
    EXPECT_LT(plain_visible, 4 * 300 / 2);
  }
}

// Identical once the tables are rounded as the archive stores them (network_archive_test.cc).
TEST(NetworkTest, SaveThenLoadGivesIdenticalPredictions) {
  const RandomMap map = MakeRandomMap(4);
  const Network network = testing_support::AsStoredInABundle(Network(map.shape, SmallOptions(), 9));
  std::stringstream stream;
  network.Save(stream);
  const Network loaded = Network::Load(stream, "memory");
  EXPECT_EQ(loaded.shape(), map.shape);
  EXPECT_EQ(loaded.options(), SmallOptions());
  EXPECT_TRUE(loaded.HasSameWeights(network));
  EXPECT_EQ(loaded.NumParameters(), network.NumParameters());
  const DescriptorMatrix descriptors = RandomDescriptors(100, map.shape.descriptor_dim, 10);
  const PointPredictions before = network.Predict(descriptors, {0, 1, 2}, map.tree);
  const PointPredictions after = loaded.Predict(descriptors, {0, 1, 2}, map.tree);
  EXPECT_EQ(before.point_indices, after.point_indices);
  EXPECT_EQ(before.labels, after.labels);
  EXPECT_EQ(before.confidences, after.confidences);
}

TEST(NetworkTest, LoadRejectsDataThatIsNoNetwork) {
  std::stringstream garbage("definitely not a torch archive");
  EXPECT_THROW(
      try { Network::Load(garbage, "bundle/network.pt"); } catch (const std::invalid_argument& e) {
        EXPECT_THAT(e.what(), HasSubstr("bundle/network.pt"));
        throw;
      },
      std::invalid_argument);
}

// A shared trunk is the first level's, held once: every level computes the same trunk output,
// the network has one trunk's parameters, and a query does one trunk's work.
TEST(NetworkTest, SharedTrunkIsOneTrunkForEveryLevel) {
  const RandomMap map = MakeRandomMap(5);
  NetworkOptions options = SmallOptions();
  options.node_output_dim = 8;
  options.pooled_point_rows = true;
  const Network per_level(map.shape, options, 3);
  options.shared_trunk = true;
  Network shared(map.shape, options, 3);
  std::vector<Level>& levels = NetworkInternals::Module(shared)->levels;
  int levels_with_weights = 0;
  for (const Level& level : levels) levels_with_weights += level->HasWeights();
  ASSERT_GE(levels_with_weights, 2);
  const int64_t d = map.shape.descriptor_dim;
  const int64_t h = options.trunk_channels;
  const int64_t c = options.channels;
  const int64_t trunk_parameters = d * h + h + h * c + c;
  EXPECT_EQ(per_level.NumParameters() - shared.NumParameters(),
            (levels_with_weights - 1) * trunk_parameters);
  int64_t named_trunk_parameters = 0;
  for (const auto& item : NetworkInternals::Module(shared)->named_parameters()) {
    if (item.key().find("trunk") != std::string::npos) {
      EXPECT_EQ(item.key().rfind("level0.", 0), 0u) << item.key();
      named_trunk_parameters += item.value().numel();
    }
  }
  EXPECT_EQ(named_trunk_parameters, trunk_parameters);

  torch::NoGradGuard no_grad;
  const torch::Tensor descriptors = torch::randn({7, d});
  const torch::Tensor first = levels[0]->Trunk(descriptors);
  for (Level& level : levels) {
    if (level->HasWeights()) {
      EXPECT_TRUE(torch::equal(level->Trunk(descriptors), first));
    }
  }
  EXPECT_FALSE(levels[0]->BorrowsTrunk());
  EXPECT_TRUE(levels[1]->BorrowsTrunk());

  const double trunk_flops = 2.0 * 100 * (d * h + h * c);
  EXPECT_DOUBLE_EQ(per_level.PredictFlops(100, 3, map.tree) - shared.PredictFlops(100, 3, map.tree),
                   (levels_with_weights - 1) * trunk_flops);

  // Per-level trunks holding copies of the shared one compute the same, with more work.
  Network copies(
      map.shape,
      [&] {
        NetworkOptions per_level_options = options;
        per_level_options.shared_trunk = false;
        return per_level_options;
      }(),
      3);
  const auto shared_weights = NetworkInternals::Module(shared)->named_parameters();
  for (auto& item : NetworkInternals::Module(copies)->named_parameters()) {
    std::string name = item.key();
    if (name.find(".trunk") != std::string::npos) name = "level0" + name.substr(name.find('.'));
    item.value().copy_(shared_weights[name]);
  }
  const DescriptorMatrix queries = RandomDescriptors(100, d, 4);
  const PointPredictions of_shared = shared.Predict(queries, {0, 1, 2}, map.tree);
  const PointPredictions of_copies = copies.Predict(queries, {0, 1, 2}, map.tree);
  EXPECT_EQ(of_shared.labels, of_copies.labels);
  EXPECT_EQ(of_shared.confidences, of_copies.confidences);
  const auto total = [](const PointPredictions& predictions) {
    return std::accumulate(predictions.level_flops.begin(), predictions.level_flops.end(), 0.0);
  };
  EXPECT_DOUBLE_EQ(total(of_copies) - total(of_shared), (levels_with_weights - 1) * trunk_flops);
}

TEST(NetworkTest, SeedDeterminesTheInitialWeights) {
  const RandomMap map = MakeRandomMap(5);
  const Network a(map.shape, SmallOptions(), 11);
  const Network b(map.shape, SmallOptions(), 11);
  const Network c(map.shape, SmallOptions(), 12);
  EXPECT_TRUE(a.HasSameWeights(b));
  EXPECT_FALSE(a.HasSameWeights(c));
}

TEST(NetworkTest, RejectsInputsThatDoNotFit) {
  const RandomMap map = MakeRandomMap(6);
  const Network network(map.shape, SmallOptions(), 1);
  const DescriptorMatrix descriptors = RandomDescriptors(10, map.shape.descriptor_dim, 1);
  EXPECT_THROW(network.Predict(RandomDescriptors(10, 16, 1), {0}, map.tree), std::invalid_argument);
  EXPECT_THROW(network.Predict(descriptors, {network.NoImageIndex() + 1}, map.tree),
               std::invalid_argument);
  const Visibility other = Visibility::FromObservations(3, 600, {0}, {1});
  EXPECT_THROW(network.Predict(descriptors, {0}, map.tree, &other), std::invalid_argument);
  NetworkShape deeper = map.shape;
  deeper.levels = 4;
  deeper.nodes_per_depth.push_back(deeper.nodes_per_depth.back());
  const Network deeper_network(deeper, SmallOptions(), 1);
  EXPECT_THROW(deeper_network.Predict(descriptors, {0}, map.tree), std::invalid_argument);
  if (!IsComputeDeviceAvailable(ComputeDevice::kCuda)) {
    EXPECT_THROW(Network(map.shape, SmallOptions(), 1).SetDevice(ComputeDevice::kCuda),
                 std::invalid_argument);
  }
}

TEST(NetworkTest, FlopCountGrowsWithTheImageBatch) {
  const RandomMap map = MakeRandomMap(7);
  const Network network(map.shape, SmallOptions(), 1);
  const double one = network.PredictFlops(1000, 1, map.tree);
  const double ten = network.PredictFlops(1000, 10, map.tree);
  EXPECT_GT(one, 0);
  EXPECT_GT(ten, 5 * one);
  EXPECT_LT(ten, 10 * one);
}

}  // namespace
}  // namespace hscloc
