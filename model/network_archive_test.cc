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

// The archive as version 1 wrote it: three options (no trunk width, which equalled the channels).
std::string VersionOneArchive(const Network& network) {
  torch::serialize::OutputArchive archive;
  const NetworkShape& shape = network.shape();
  const NetworkOptions& options = network.options();
  archive.write("format", torch::tensor(std::vector<int64_t>{0x4e435348, 1}, torch::kInt64));
  archive.write("shape", torch::tensor(std::vector<int64_t>{shape.descriptor_dim, shape.levels,
                                                            shape.branching, shape.num_images},
                                       torch::kInt64));
  archive.write("options",
                torch::tensor(std::vector<int64_t>{options.channels, options.embedding_dim,
                                                   options.conditioned_layers},
                              torch::kInt64));
  torch::serialize::OutputArchive weights;
  NetworkInternals::Module(network)->save(weights);
  archive.write("weights", weights);
  std::ostringstream stream;
  archive.save_to(stream);
  return stream.str();
}

TEST(NetworkArchiveTest, VersionOneArchivesLoadWithTheTrunkAsWideAsTheChannels) {
  const RandomMap map = MakeRandomMap(12);
  NetworkOptions options;
  options.channels = 36;
  options.trunk_channels = 36;
  options.embedding_dim = 12;
  const Network network(map.shape, options, 3);
  std::istringstream stream(VersionOneArchive(network));
  const Network loaded = Network::Load(stream, "v1.pt");
  EXPECT_EQ(loaded.options(), options);
  EXPECT_TRUE(loaded.HasSameWeights(network));
  const DescriptorMatrix descriptors = RandomDescriptors(50, map.shape.descriptor_dim, 4);
  EXPECT_EQ(loaded.Predict(descriptors, {1, 2}, map.tree).labels,
            network.Predict(descriptors, {1, 2}, map.tree).labels);
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
