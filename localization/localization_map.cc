#include "localization/localization_map.h"

#include "map/map_bundle.h"
#include "scene/scene_io.h"
#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

constexpr uint32_t kGlobalDescriptorsMagic = 0x44475348;  // "HSGD"
constexpr uint32_t kGlobalDescriptorsVersion = 1;

// Deserializes one blob, prefixing any error with the bundle so the operator knows which map.
// The blob's bytes are freed once parsed, so loading holds one raw blob at a time beside the map.
template <typename Reader>
auto ReadBlob(MapBundle& bundle, const char* name, Reader read) {
  if (!bundle.HasBlob(name)) {
    ThrowInvalidArgument("map bundle {}: blob '{}' is missing", bundle.dir().string(), name);
  }
  const std::string bytes = bundle.TakeBlob(name);
  MemoryInputStream stream(bytes);
  const std::string source = (bundle.dir() / name).string();
  return read(stream, source);
}

}  // namespace

void WriteGlobalDescriptors(std::ostream& stream, const GlobalDescriptorMatrix& descriptors) {
  WriteBinary(stream, kGlobalDescriptorsMagic);
  WriteBinary(stream, kGlobalDescriptorsVersion);
  WriteBinary<uint64_t>(stream, descriptors.rows());
  WriteBinary<uint64_t>(stream, descriptors.cols());
  WriteBinaryArray(stream, descriptors.data(), descriptors.size());
}

GlobalDescriptorMatrix ReadGlobalDescriptors(std::istream& stream, const std::string& source) {
  if (ReadBinary<uint32_t>(stream, source + ": magic") != kGlobalDescriptorsMagic ||
      ReadBinary<uint32_t>(stream, source + ": version") != kGlobalDescriptorsVersion) {
    ThrowInvalidArgument("{}: not a global descriptor blob of version {}", source,
                         kGlobalDescriptorsVersion);
  }
  const auto rows = ReadBinary<uint64_t>(stream, source + ": rows");
  const auto cols = ReadBinary<uint64_t>(stream, source + ": columns");
  if (rows > (uint64_t{1} << 32) || cols > (uint64_t{1} << 20)) {
    ThrowInvalidArgument("{}: impossible shape {} x {}", source, rows, cols);
  }
  GlobalDescriptorMatrix descriptors(rows, cols);
  ReadBinaryArray(stream, descriptors.data(), descriptors.size(), source + ": descriptors");
  return descriptors;
}

std::shared_ptr<const LocalizationMap> LocalizationMap::Load(
    const std::filesystem::path& bundle_dir, const LocalizationMapLoadOptions& options) {
  // Only the blobs this map needs are read and verified: a serving map skips the observations'
  // descriptors (most of a map's bytes), a map without its network skips the network.
  std::vector<std::string> blobs = {
      map_blobs::kScene, map_blobs::kLabelTree,         map_blobs::kVisibility,
      map_blobs::kVlad,  map_blobs::kGlobalDescriptors, map_blobs::kGlobalIndex};
  if (options.load_observations) blobs.push_back(map_blobs::kObservations);
  if (options.load_network) blobs.push_back(map_blobs::kNetwork);
  if (options.load_point_descriptors) blobs.push_back(map_blobs::kPointDescriptors);
  MapBundle bundle = MapBundle::Open(bundle_dir, blobs);
  auto map = std::make_shared<LocalizationMap>();
  map->dir_ = bundle_dir;
  map->metadata_ = bundle.metadata();
  map->manifest_sha256_ = bundle.manifest_sha256();
  map->scene_ = ReadBlob(bundle, map_blobs::kScene, ReadSceneGeometry);
  if (options.load_observations) {
    ReadBlob(bundle, map_blobs::kObservations,
             [&](std::istream& stream, const std::string& source) {
               ReadSceneObservations(stream, source, map->scene_);
               return 0;
             });
  }
  map->label_tree_ = ReadBlob(bundle, map_blobs::kLabelTree, LabelTree::Read);
  map->visibility_ = ReadBlob(bundle, map_blobs::kVisibility, Visibility::Read);
  if (options.load_point_descriptors && bundle.HasBlob(map_blobs::kPointDescriptors)) {
    map->point_descriptors_ =
        ReadBlob(bundle, map_blobs::kPointDescriptors, PointDescriptors::Read);
  }
  if (bundle.HasBlob(map_blobs::kVlad)) {
    map->vlad_ = ReadBlob(bundle, map_blobs::kVlad, VladEncoder::Read);
  }
  map->global_descriptors_ = ReadBlob(bundle, map_blobs::kGlobalDescriptors, ReadGlobalDescriptors);
  map->global_index_ = ReadBlob(bundle, map_blobs::kGlobalIndex, GlobalIndex::Read);
  map->descriptor_dim_ = map->metadata_.value(map_metadata::kDescriptorDim, 0);
  if (options.load_network && bundle.HasBlob(map_blobs::kNetwork)) {
    map->network_ = std::make_shared<const Network>(Network::FromBundle(bundle, options.device));
  }

  // The parts were written together; a mismatch means a bundle assembled from different maps.
  const auto fail = [&](const std::string& what) {
    ThrowInvalidArgument("map bundle {}: inconsistent parts: {}", bundle_dir.string(), what);
  };
  const Scene& scene = map->scene_;
  if (map->label_tree_.NumPoints() != scene.NumPoints()) {
    fail(fmt::format("label tree of {} points, scene of {}", map->label_tree_.NumPoints(),
                     scene.NumPoints()));
  }
  if (map->visibility_.NumImages() != scene.NumImages() ||
      map->visibility_.NumPoints() != scene.NumPoints()) {
    fail("visibility lists do not match the scene's images and points");
  }
  if (!map->point_descriptors_.empty() &&
      (map->point_descriptors_.NumPoints() != scene.NumPoints() ||
       map->point_descriptors_.Dimension() != map->descriptor_dim_)) {
    fail(fmt::format("{} point descriptors of dimension {}, scene of {} points of dimension {}",
                     map->point_descriptors_.NumPoints(), map->point_descriptors_.Dimension(),
                     scene.NumPoints(), map->descriptor_dim_));
  }
  if (map->global_index_.size() != scene.NumImages() ||
      static_cast<size_t>(map->global_descriptors_.rows()) != scene.NumImages()) {
    fail("retrieval index does not hold one descriptor per database image");
  }
  if (map->vlad_ && map->vlad_->descriptor_dim() != map->descriptor_dim_) {
    fail(fmt::format("VLAD codebook of dimension {}, map descriptors of {}",
                     map->vlad_->descriptor_dim(), map->descriptor_dim_));
  }
  return map;
}

}  // namespace hscloc
