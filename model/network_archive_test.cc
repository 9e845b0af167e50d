// Network archives written by earlier versions still load: maps trained before a format change
// keep working without retraining.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <functional>
#include <sstream>

#include "model/network.h"
#include "model/network_module.h"
#include "model/network_test_support.h"

namespace hscloc {
namespace {

using testing_support::AsStoredInABundle;
using testing_support::CopyAtFullPrecision;
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
  for (NetworkOptions options :
       testing_support::HeadVariants(testing_support::SmallOptions(), map.shape.descriptor_dim)) {
    options.masked_decoding = options.node_output_dim > 0;
    const Network network(map.shape, options, 5);
    std::stringstream stream;
    network.Save(stream);
    const Network loaded = Network::Load(stream, "current.pt");
    EXPECT_EQ(loaded.options(), options);
    EXPECT_EQ(loaded.shape().nodes_per_depth, map.shape.nodes_per_depth);
    const Network expected_network = AsStoredInABundle(network);
    EXPECT_TRUE(loaded.HasSameWeights(expected_network));
    const DescriptorMatrix descriptors = RandomDescriptors(60, map.shape.descriptor_dim, 8);
    const PointPredictions expected = expected_network.Predict(descriptors, {0, 4}, map.tree);
    const PointPredictions actual = loaded.Predict(descriptors, {0, 4}, map.tree);
    EXPECT_EQ(actual.labels, expected.labels);
    EXPECT_EQ(actual.confidences, expected.confidences);
  }
}

// Small pooled point rows, decoded with the visibility mask.
NetworkOptions PooledRowOptions() {
  NetworkOptions options = testing_support::SmallOptions();
  options.node_conditioning = false;
  options.pooled_point_rows = true;
  options.masked_decoding = true;
  return options;
}

TEST(NetworkArchiveTest, SeveralRowsPerPointKeepTheirOffsets) {
  const RandomMap map = MakeRandomMap(12);
  const NetworkShape shape = testing_support::WithPrototypeRows(map.shape);
  const NetworkOptions options = PooledRowOptions();
  const Network network(shape, options, 5);
  std::stringstream stream;
  network.Save(stream);
  const Network loaded = Network::Load(stream, "prototypes.pt");
  EXPECT_EQ(loaded.shape(), shape);
  EXPECT_TRUE(loaded.HasSameWeights(AsStoredInABundle(network)));
  const DescriptorMatrix descriptors = RandomDescriptors(60, shape.descriptor_dim, 8);
  EXPECT_EQ(
      loaded.Predict(descriptors, {0, 4}, map.tree, &map.visibility).labels,
      AsStoredInABundle(network).Predict(descriptors, {0, 4}, map.tree, &map.visibility).labels);

  NetworkShape without_rows = shape;
  without_rows.point_row_offsets[5] = without_rows.point_row_offsets[4];
  EXPECT_THROW(Network(without_rows, options, 5), std::invalid_argument);
  NetworkOptions unpooled = options;
  unpooled.pooled_point_rows = false;
  EXPECT_THROW(Network(shape, unpooled, 5), std::invalid_argument);
}

// A bundle stores every matrix as 8-bit rows, each element within half a row's step of the
// trained value, and every vector exactly; a checkpoint keeps all as trained.
TEST(NetworkArchiveTest, BundlesStoreMatricesAsEightBitRowsAndCheckpointsEverything) {
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
  EXPECT_TRUE(loaded.HasSameWeights(AsStoredInABundle(network)));
  const auto original = NetworkInternals::Module(network)->named_parameters();
  int matrices = 0;
  for (const auto& item : NetworkInternals::Module(loaded)->named_parameters()) {
    const torch::Tensor& before = original[item.key()];
    if (before.dim() == 2) {
      ++matrices;
      const torch::Tensor step = before.abs().amax(1, true) / 127;
      EXPECT_TRUE(((item.value() - before).abs() <= step / 2 * (1 + 1e-5)).all().item<bool>())
          << item.key();
    } else {
      EXPECT_TRUE(torch::equal(item.value(), before)) << item.key();
    }
  }
  EXPECT_GE(matrices, 8 * map.shape.levels);
}

// 8-bit rows: the largest magnitude of a row is kept, a zero row stays zero, values already on a
// row's grid come back exactly, and the rows take a quarter of the bytes.
TEST(NetworkArchiveTest, EightBitRowsKeepEachRowsScale) {
  const torch::Tensor matrix =
      torch::tensor({0.f, 0.f, 0.f, 1.f, -0.5f, 0.25f, 127.f, -3.f, 64.f}).view({3, 3});
  const Int8Rows rows = QuantizeRows(matrix);
  EXPECT_EQ(rows.values.scalar_type(), torch::kInt8);
  EXPECT_TRUE(torch::equal(rows.values[0], torch::zeros({3}, torch::kInt8)));
  EXPECT_FLOAT_EQ(rows.scales[1].item<float>(), 1.f / 127);
  EXPECT_EQ(rows.values[1][0].item<int>(), 127);
  EXPECT_EQ(rows.values[1][1].item<int>(), -64);  // -63.5 rounds away from zero
  EXPECT_TRUE(torch::equal(DequantizeRows(rows)[2], matrix[2]));
  const torch::Tensor noise = torch::randn({50, 40}) * torch::rand({50, 1}) * 10;
  const torch::Tensor back = DequantizeRows(QuantizeRows(noise));
  EXPECT_TRUE(
      ((back - noise).abs() <= noise.abs().amax(1, true) / 254 * (1 + 1e-5)).all().item<bool>());
  EXPECT_TRUE(torch::allclose(back.abs().amax(1), noise.abs().amax(1), 1e-6, 0));
}

// The bundle's archive is about a quarter of the checkpoint's, and a level whose parents all
// have one child holds no weights at all.
TEST(NetworkArchiveTest, BundlesAreAQuarterOfTheWeightsAndSkipLevelsWithoutAChoice) {
  const RandomMap map = MakeRandomMap(12);
  NetworkOptions options = testing_support::SmallOptions();
  options.channels = 64;
  options.trunk_channels = 64;
  const Network network(map.shape, options, 7);
  torch::serialize::OutputArchive checkpoint;
  NetworkInternals::SaveTo(network, checkpoint, WeightStorage::kFloat32);
  std::ostringstream full;
  checkpoint.save_to(full);
  std::ostringstream bundle;
  network.Save(bundle);
  EXPECT_LT(bundle.str().size(), 0.35 * full.str().size());

  // A map of 10 points under a tree of 3 levels, branching 12: only the first level chooses.
  NetworkShape shape = map.shape;
  shape.nodes_per_depth = {1, 10, 10, 10};
  const Network shallow(shape, testing_support::SmallOptions(), 7);
  const auto& levels = NetworkInternals::Module(shallow)->levels;
  EXPECT_TRUE(levels[0]->HasWeights());
  EXPECT_GT(levels[0]->parameters().size(), 0u);
  for (size_t level = 1; level < levels.size(); ++level) {
    EXPECT_FALSE(levels[level]->HasWeights());
    EXPECT_TRUE(levels[level]->parameters().empty());
  }
  EXPECT_LT(shallow.NumParameters(),
            Network(map.shape, testing_support::SmallOptions(), 7).NumParameters() / 2);
}

// A matrix holding a value that is not finite is stored as it is.
TEST(NetworkArchiveTest, MatricesWithNonFiniteValuesStayExact) {
  const RandomMap map = MakeRandomMap(12);
  const Network network(map.shape, testing_support::SmallOptions(), 7);
  Network odd = CopyAtFullPrecision(network);
  {
    torch::NoGradGuard no_grad;
    for (auto& item : NetworkInternals::Module(odd)->named_parameters()) {
      if (item.value().dim() == 2) item.value().view({-1})[0].fill_(INFINITY);
    }
  }
  std::stringstream stream;
  odd.Save(stream);
  EXPECT_TRUE(Network::Load(stream, "odd.pt").HasSameWeights(odd));
}

// The network's current archive with `format` replaced and each weight passed through `weight`.
// `extra_weights` are written beside them.
std::string RewrittenArchive(
    const Network& network, const std::vector<int64_t>& format,
    const std::function<torch::Tensor(const std::string&, const torch::Tensor&)>& weight,
    const std::vector<std::pair<std::string, torch::Tensor>>& extra_weights = {}) {
  std::stringstream stream;
  network.Save(stream);
  torch::serialize::InputArchive archive;
  archive.load_from(stream);
  torch::serialize::OutputArchive rewritten;
  for (const std::string& key : archive.keys()) {
    torch::Tensor tensor;
    if (!archive.try_read(key, tensor)) continue;
    if (key == "format") tensor = torch::tensor(format, torch::kInt64);
    // Versions 4 and 5 wrote eight options (no descriptor shortcut), 6 and 7 nine (no shared
    // trunk).
    if (key == "options" && format[1] <= 5) tensor = tensor.narrow(0, 0, 8);
    if (key == "options" && (format[1] == 6 || format[1] == 7)) tensor = tensor.narrow(0, 0, 9);
    rewritten.write(key, tensor);
  }
  torch::serialize::OutputArchive weights;
  for (const auto& item : NetworkInternals::Module(network)->named_parameters()) {
    weights.write(item.key(), weight(item.key(), item.value()));
  }
  for (const auto& [name, tensor] : extra_weights) weights.write(name, tensor);
  rewritten.write("weights", weights);
  std::ostringstream bytes;
  rewritten.save_to(bytes);
  return bytes.str();
}

// A version 9 network of several rows per point was trained for each point's best row: its biases
// are shifted by -log of their point's rows on load, so that a point scores its rows' mean
// exponential; a version 9 network of one row per point loads as it was.
TEST(NetworkArchiveTest, VersionNineRowsPerViewScoreTheirMeanExponential) {
  const RandomMap map = MakeRandomMap(12);
  const NetworkShape shape = testing_support::WithPrototypeRows(map.shape);
  const NetworkOptions options = PooledRowOptions();
  const Network network(shape, options, 5);
  const auto unchanged = [](const std::string&, const torch::Tensor& tensor) { return tensor; };
  std::istringstream input(RewrittenArchive(network, {0x4e435348, 9}, unchanged));
  const Network loaded = Network::Load(input, "v9.pt");
  const torch::Tensor trained = NetworkInternals::Module(network)->point_rows;
  const torch::Tensor shifted = NetworkInternals::Module(loaded)->point_rows;
  const int64_t bias = trained.size(1) - 1;
  for (size_t rank = 0; rank + 1 < shape.point_row_offsets.size(); ++rank) {
    const int64_t first = shape.point_row_offsets[rank];
    const int64_t count = shape.point_row_offsets[rank + 1] - first;
    for (int64_t row = first; row < first + count; ++row) {
      EXPECT_NEAR(shifted[row][bias].item<float>(),
                  trained[row][bias].item<float>() - std::log(static_cast<float>(count)), 1e-5);
      EXPECT_TRUE(torch::equal(shifted[row].narrow(0, 0, bias), trained[row].narrow(0, 0, bias)));
    }
  }

  const Network one_row(map.shape, options, 5);
  std::istringstream one_row_input(RewrittenArchive(one_row, {0x4e435348, 9}, unchanged));
  EXPECT_TRUE(Network::Load(one_row_input, "v9-one-row.pt").HasSameWeights(one_row));
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
  EXPECT_FALSE(loaded.options().shared_trunk);
  EXPECT_TRUE(loaded.HasSameWeights(network));
}

// Version 6 archives stored weights for the levels without a choice too: they load, unread.
TEST(NetworkArchiveTest, VersionSixWeightsOfLevelsWithoutAChoiceAreLeftUnread) {
  NetworkShape shape = MakeRandomMap(12).shape;
  shape.nodes_per_depth = {1, 10, 10, 10};
  const Network network(shape, testing_support::SmallOptions(), 3);
  std::istringstream input(
      RewrittenArchive(network, {0x4e435348, 6},
                       [](const std::string&, const torch::Tensor& tensor) { return tensor; },
                       {{"level1.trunk1.weight", torch::ones({4, 4})},
                        {"level2.generator.bias", torch::ones({4})}}));
  const Network loaded = Network::Load(input, "v6.pt");
  EXPECT_TRUE(loaded.HasSameWeights(network));
  EXPECT_EQ(loaded.NumParameters(), network.NumParameters());
}

// 8-bit rows without their scales are named, not misread.
TEST(NetworkArchiveTest, EightBitRowsWithoutScalesAreNamed) {
  const RandomMap map = MakeRandomMap(12);
  const Network network(map.shape, testing_support::SmallOptions(), 3);
  std::istringstream input(RewrittenArchive(
      network, {0x4e435348, 7}, [](const std::string& name, const torch::Tensor& tensor) {
        return name == "level0.trunk2.weight" ? QuantizeRows(tensor).values : tensor;
      }));
  try {
    Network::Load(input, "unscaled.pt");
    FAIL() << "8-bit rows without scales loaded";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("unscaled.pt: network weight 'level0.trunk2.weight'"),
              std::string::npos)
        << error.what();
  }
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
