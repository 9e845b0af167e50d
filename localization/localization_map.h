// A map as the localizer uses it: the scene geometry, the label tree, the visibility lists and the
// retrieval index, loaded read-only from a verified map bundle (`hscloc build-map`).
//
// Bundle blobs (docs/formats.md): scene.bin, observations.bin, label_tree.bin, visibility.bin,
// point_descriptors.bin (absent from maps built before it), global_descriptors.bin,
// global_index.bin, and vlad.bin when the global descriptors are computed from local features
// (absent when they came from an external .h5).
#pragma once

#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "map/label_tree.h"
#include "map/map_blobs.h"
#include "map/point_descriptors.h"
#include "map/visibility.h"
#include "model/network.h"
#include "retrieval/global_index.h"
#include "retrieval/vlad.h"
#include "scene/scene.h"

namespace hscloc {

using GlobalDescriptorMatrix =
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct LocalizationMapLoadOptions {
  // Observations (descriptors of every database observation) are needed for training and the
  // explicit-matching baseline, not for classification-based localization.
  bool load_observations = false;
  // The trained network, when the bundle has one, read from the same verified opening of the
  // bundle as the other parts (so map and network always come from one version of it).
  bool load_network = true;
  // Each point's mean descriptor, when the bundle has it: what the localizer matches against
  // where the network leaves a query without a pose (256 bytes a point at D = 256).
  bool load_point_descriptors = true;
  ComputeDevice device = ComputeDevice::kCpu;
};

class LocalizationMap {
 public:
  // Opens and verifies the bundle (checksums, versions) and deserializes its parts. Throws
  // std::invalid_argument naming the bundle and the bad part.
  static std::shared_ptr<const LocalizationMap> Load(
      const std::filesystem::path& bundle_dir, const LocalizationMapLoadOptions& options = {});

  const std::filesystem::path& dir() const { return dir_; }
  const nlohmann::json& metadata() const { return metadata_; }
  // The bundle's manifest hash as loaded (MapBundle::manifest_sha256).
  const std::string& manifest_sha256() const { return manifest_sha256_; }
  const Scene& scene() const { return scene_; }
  const LabelTree& label_tree() const { return label_tree_; }
  const Visibility& visibility() const { return visibility_; }
  // Empty when the bundle has none or they were not asked for.
  const PointDescriptors& point_descriptors() const { return point_descriptors_; }
  // Absent when the map's global descriptors came from an external file: queries must then send
  // their own global descriptor.
  const std::optional<VladEncoder>& vlad() const { return vlad_; }
  const GlobalIndex& global_index() const { return global_index_; }
  const GlobalDescriptorMatrix& global_descriptors() const { return global_descriptors_; }
  int descriptor_dim() const { return descriptor_dim_; }
  // Null when the bundle has no trained network or it was not asked for.
  const std::shared_ptr<const Network>& network() const { return network_; }

 private:
  std::filesystem::path dir_;
  nlohmann::json metadata_;
  std::string manifest_sha256_;
  Scene scene_;
  LabelTree label_tree_;
  Visibility visibility_;
  PointDescriptors point_descriptors_;
  std::optional<VladEncoder> vlad_;
  GlobalIndex global_index_;
  GlobalDescriptorMatrix global_descriptors_;
  int descriptor_dim_ = 0;
  std::shared_ptr<const Network> network_;
};

void WriteGlobalDescriptors(std::ostream& stream, const GlobalDescriptorMatrix& descriptors);
GlobalDescriptorMatrix ReadGlobalDescriptors(std::istream& stream, const std::string& source);

}  // namespace hscloc
