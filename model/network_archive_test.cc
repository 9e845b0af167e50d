// Network archives written by earlier versions still load: maps trained before a format change
// keep working without retraining.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <functional>
#include <sstream>

#include "model/network.h"
#include "model/network_module.h"
#include "model/network_test_support.h"

namespace hscloc {
namespace {

using testing_support::CopyAtFullPrecision;
using testing_support::MakeRandomMap;
using testing_support::RandomDescriptors;
using testing_support::RandomMap;
using testing_support::WithTablesRoundedToHalf;

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
  for (NetworkOptions options :
       testing_support::HeadVariants(testing_support::SmallOptions(), map.shape.descriptor_dim)) {
    options.masked_decoding = options.node_output_dim > 0;
    const Network network(map.shape, options, 5);
    std::stringstream stream;
    network.Save(stream);
    const Network loaded = Network::Load(stream, "current.pt");
    EXPECT_EQ(loaded.options(), options);
    EXPECT_EQ(loaded.shape().nodes_per_depth, map.shape.nodes_per_depth);
    const Network expected_network = WithTablesRoundedToHalf(network);
    EXPECT_TRUE(loaded.HasSameWeights(expected_network));
    const DescriptorMatrix descriptors = RandomDescriptors(60, map.shape.descriptor_dim, 8);
    const PointPredictions expected = expected_network.Predict(descriptors, {0, 4}, map.tree);
    const PointPredictions actual = loaded.Predict(descriptors, {0, 4}, map.tree);
    EXPECT_EQ(actual.labels, expected.labels);
    EXPECT_EQ(actual.confidences, expected.confidences);
  }
}

// Only the tables are rounded: every other weight is kept exactly, and a checkpoint keeps all.
TEST(NetworkArchiveTest, BundlesRoundOnlyTheTablesAndCheckpointsNothing) {
  const RandomMap map = MakeRandomMap(12);
  NetworkOptions options = testing_support::SmallOptions();
  options.node_conditioning = true;
  options.node_output_dim = 8;
  options.pooled_point_rows = true;
  const Network network(map.shape, options, 7);
  EXPECT_TRUE(CopyAtFullPrecision(network).HasSameWeights(network));

  std::stringstream stream;
  network.Save(stream);
  const Network loaded = Network::Load(stream, "bundle.pt");
  EXPECT_FALSE(loaded.HasSameWeights(network));
  const auto original = NetworkInternals::Module(network)->named_parameters();
  int tables = 0;
  for (const auto& item : NetworkInternals::Module(loaded)->named_parameters()) {
    const torch::Tensor& before = original[item.key()];
    if (IsMapSizedTable(item.key())) {
      ++tables;
      EXPECT_TRUE(torch::equal(item.value(), before.to(torch::kHalf).to(torch::kFloat)))
          << item.key();
      // Half precision keeps 11 significant bits.
      EXPECT_LE((item.value() - before).abs().max().item<float>(),
                std::ldexp(before.abs().max().item<float>(), -11))
          << item.key();
    } else {
      EXPECT_TRUE(torch::equal(item.value(), before)) << item.key();
    }
  }
  // Image embeddings and node embeddings of every level, and the point rows.
  EXPECT_GE(tables, 2 * map.shape.levels);
}

// A table with a value half precision cannot hold stays at full precision.
TEST(NetworkArchiveTest, TablesBeyondTheHalfRangeStayExact) {
  const RandomMap map = MakeRandomMap(12);
  const Network network(map.shape, testing_support::SmallOptions(), 7);
  Network large = CopyAtFullPrecision(network);
  {
    torch::NoGradGuard no_grad;
    for (auto& item : NetworkInternals::Module(large)->named_parameters()) {
      if (IsMapSizedTable(item.key())) item.value().view({-1})[0].fill_(1e6);
    }
  }
  std::stringstream stream;
  large.Save(stream);
  EXPECT_TRUE(Network::Load(stream, "large.pt").HasSameWeights(large));
}

// The network's current archive with `format` replaced and each weight passed through `weight`.
std::string RewrittenArchive(
    const Network& network, const std::vector<int64_t>& format,
    const std::function<torch::Tensor(const std::string&, const torch::Tensor&)>& weight) {
  std::stringstream stream;
  network.Save(stream);
  torch::serialize::InputArchive archive;
  archive.load_from(stream);
  torch::serialize::OutputArchive rewritten;
  for (const std::string& key : archive.keys()) {
    torch::Tensor tensor;
    if (!archive.try_read(key, tensor)) continue;
    if (key == "format") tensor = torch::tensor(format, torch::kInt64);
    // Versions 4 and 5 wrote eight options (no descriptor shortcut).
    if (key == "options" && format[1] <= 5) tensor = tensor.narrow(0, 0, 8);
    rewritten.write(key, tensor);
  }
  torch::serialize::OutputArchive weights;
  for (const auto& item : NetworkInternals::Module(network)->named_parameters()) {
    weights.write(item.key(), weight(item.key(), item.value()));
  }
  rewritten.write("weights", weights);
  std::ostringstream bytes;
  rewritten.save_to(bytes);
  return bytes.str();
}

// An archive whose weights do not fit the network says which weight.
TEST(NetworkArchiveTest, MismatchedWeightsAreNamed) {
  const RandomMap map = MakeRandomMap(12);
  const Network network(map.shape, testing_support::SmallOptions(), 3);
  std::istringstream input(RewrittenArchive(
      network, {0x4e435348, 6}, [](const std::string& name, const torch::Tensor& tensor) {
        return name == "level0.trunk1.weight" ? tensor.t() : tensor;
      }));
  try {
    Network::Load(input, "changed.pt");
    FAIL() << "mismatched weights loaded";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("changed.pt: network weight 'level0.trunk1.weight'"),
              std::string::npos)
        << error.what();
  }
}

// Version 5 archives (pooled point rows, before the descriptor shortcut) load as they were.
TEST(NetworkArchiveTest, VersionFiveArchivesLoadWithoutTheDescriptorShortcut) {
  const RandomMap map = MakeRandomMap(12);
  NetworkOptions options = testing_support::SmallOptions();
  options.node_output_dim = 8;
  options.pooled_point_rows = true;
  options.masked_decoding = true;
  const Network network(map.shape, options, 3);
  std::istringstream input(
      RewrittenArchive(network, {0x4e435348, 5},
                       [](const std::string&, const torch::Tensor& tensor) { return tensor; }));
  const Network loaded = Network::Load(input, "v5.pt");
  EXPECT_EQ(loaded.options(), options);
  EXPECT_FALSE(loaded.options().descriptor_shortcut);
  EXPECT_TRUE(loaded.HasSameWeights(network));
}

TEST(NetworkArchiveTest, ArchivesOfAnUnknownVersionAreRejectedByName) {
  const RandomMap map = MakeRandomMap(12);
  const Network network(map.shape, testing_support::SmallOptions(), 3);
  std::istringstream input(
      RewrittenArchive(network, {0x4e435348, 99},
                       [](const std::string&, const torch::Tensor& tensor) { return tensor; }));
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
