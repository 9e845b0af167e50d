// Network archives written by earlier versions still load: maps trained before a format change
// keep working without retraining.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <sstream>

#include "model/network.h"
#include "model/network_module.h"
#include "model/network_test_support.h"

namespace hscloc {
namespace {

using testing_support::MakeRandomMap;
using testing_support::RandomDescriptors;
using testing_support::RandomMap;

// The archive as version 1 (three options: no trunk width, which equalled the channels) or 2
// (four options) wrote it; neither had per-node tables or node counts.
std::string OldArchive(const Network& network, int version) {
  torch::serialize::OutputArchive archive;
  const NetworkShape& shape = network.shape();
  const NetworkOptions& options = network.options();
  archive.write("format", torch::tensor(std::vector<int64_t>{0x4e435348, version}, torch::kInt64));
  archive.write("shape", torch::tensor(std::vector<int64_t>{shape.descriptor_dim, shape.levels,
                                                            shape.branching, shape.num_images},
                                       torch::kInt64));
  std::vector<int64_t> values = {options.channels, options.embedding_dim,
                                 options.conditioned_layers};
  if (version == 2) values.push_back(options.trunk_channels);
  archive.write("options", torch::tensor(values, torch::kInt64));
  torch::serialize::OutputArchive weights;
  NetworkInternals::Module(network)->save(weights);
  archive.write("weights", weights);
  std::ostringstream stream;
  archive.save_to(stream);
  return stream.str();
}

// The shape as old archives knew it: no node counts.
NetworkShape WithoutNodeCounts(NetworkShape shape) {
  shape.nodes_per_depth.clear();
  return shape;
}

TEST(NetworkArchiveTest, VersionOneArchivesLoadWithTheTrunkAsWideAsTheChannels) {
  const RandomMap map = MakeRandomMap(12);
  NetworkOptions options = NetworkOptions::PaperFaithful();
  options.channels = 36;
  options.trunk_channels = 36;
  options.embedding_dim = 12;
  const Network network(WithoutNodeCounts(map.shape), options, 3);
  std::istringstream stream(OldArchive(network, 1));
  const Network loaded = Network::Load(stream, "v1.pt");
  EXPECT_EQ(loaded.options(), options);
  EXPECT_TRUE(loaded.HasSameWeights(network));
  const DescriptorMatrix descriptors = RandomDescriptors(50, map.shape.descriptor_dim, 4);
  EXPECT_EQ(loaded.Predict(descriptors, {1, 2}, map.tree).labels,
            network.Predict(descriptors, {1, 2}, map.tree).labels);
}

TEST(NetworkArchiveTest, VersionTwoArchivesLoadAsThePapersNetwork) {
  const RandomMap map = MakeRandomMap(12);
  NetworkOptions options = NetworkOptions::PaperFaithful();
  options.channels = 36;
  options.trunk_channels = 20;
  options.embedding_dim = 12;
  const Network network(WithoutNodeCounts(map.shape), options, 3);
  std::istringstream stream(OldArchive(network, 2));
  const Network loaded = Network::Load(stream, "v2.pt");
  EXPECT_EQ(loaded.options(), options);
  EXPECT_FALSE(loaded.options().node_conditioning);
  EXPECT_EQ(loaded.options().node_output_dim, 0);
  EXPECT_TRUE(loaded.HasSameWeights(network));
  const DescriptorMatrix descriptors = RandomDescriptors(50, map.shape.descriptor_dim, 4);
  EXPECT_EQ(loaded.Predict(descriptors, {1, 2}, map.tree, &map.visibility).labels,
            network.Predict(descriptors, {1, 2}, map.tree, &map.visibility).labels);
}

TEST(NetworkArchiveTest, CurrentVersionKeepsOutputTablesDecodingAndCounts) {
  const RandomMap map = MakeRandomMap(12);
  for (NetworkOptions options : testing_support::HeadVariants(testing_support::SmallOptions())) {
    options.masked_decoding = options.node_output_dim > 0;
    const Network network(map.shape, options, 5);
    std::stringstream stream;
    network.Save(stream);
    const Network loaded = Network::Load(stream, "v4.pt");
    EXPECT_EQ(loaded.options(), options);
    EXPECT_EQ(loaded.shape().nodes_per_depth, map.shape.nodes_per_depth);
    EXPECT_TRUE(loaded.HasSameWeights(network));
    const DescriptorMatrix descriptors = RandomDescriptors(60, map.shape.descriptor_dim, 8);
    const PointPredictions expected = network.Predict(descriptors, {0, 4}, map.tree);
    const PointPredictions actual = loaded.Predict(descriptors, {0, 4}, map.tree);
    EXPECT_EQ(actual.labels, expected.labels);
    EXPECT_EQ(actual.confidences, expected.confidences);
  }
}

TEST(NetworkArchiveTest, ArchivesOfAnUnknownVersionAreRejectedByName) {
  const RandomMap map = MakeRandomMap(12);
  const Network network(map.shape, testing_support::SmallOptions(), 3);
  std::stringstream stream;
  network.Save(stream);
  torch::serialize::InputArchive archive;
  archive.load_from(stream);
  torch::serialize::OutputArchive future;
  for (const std::string& key : archive.keys()) {
    torch::Tensor tensor;
    if (archive.try_read(key, tensor)) {
      future.write(key, key == "format"
                            ? torch::tensor(std::vector<int64_t>{0x4e435348, 99}, torch::kInt64)
                            : tensor);
    }
  }
  torch::serialize::OutputArchive weights;
  NetworkInternals::Module(network)->save(weights);
  future.write("weights", weights);
  std::ostringstream bytes;
  future.save_to(bytes);
  std::istringstream input(bytes.str());
  try {
    Network::Load(input, "future.pt");
    FAIL() << "an archive of version 99 loaded";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("future.pt"), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("version 99"), std::string::npos) << error.what();
  }
}

}  // namespace
}  // namespace hscloc
