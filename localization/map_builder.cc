#include "localization/map_builder.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <optional>

#include "localization/localization_map.h"
#include "map/map_blobs.h"
#include "map/map_bundle.h"
#include "map/point_descriptors.h"
#include "map/visibility.h"
#include "scene/colmap_io.h"
#include "scene/scene.h"
#include "scene/scene_io.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// Images encoded per parallel batch; feature readers (SQLite, HDF5) are read from one thread.
constexpr size_t kVladBatchSize = 64;

std::string IndexTypeName(GlobalIndexOptions::Type type) {
  return type == GlobalIndexOptions::Type::kFlat ? "flat" : "ivfpq";
}

GlobalDescriptorMatrix ExternalGlobalDescriptors(const Scene& scene, const fs::path& path) {
  const auto by_name = ReadH5GlobalDescriptors(path);
  GlobalDescriptorMatrix descriptors;
  for (size_t i = 0; i < scene.NumImages(); ++i) {
    const std::string& name = scene.images[i].name;
    const auto found = by_name.find(name);
    if (found == by_name.end()) {
      ThrowInvalidArgument("global descriptors {}: no descriptor for database image '{}'",
                           path.string(), name);
    }
    if (i == 0) descriptors.resize(scene.NumImages(), found->second.size());
    if (found->second.size() != descriptors.cols()) {
      ThrowInvalidArgument("global descriptors {}: image '{}' has dimension {}, others {}",
                           path.string(), name, found->second.size(), descriptors.cols());
    }
    const float norm = found->second.norm();
    if (!(norm > 0)) {
      ThrowInvalidArgument("global descriptors {}: image '{}' has a zero or non-finite descriptor",
                           path.string(), name);
    }
    descriptors.row(i) = found->second.transpose() / norm;
  }
  return descriptors;
}

VladEncoder TrainVlad(const Scene& scene, const FeatureReader& features,
                      const MapBuildOptions& options) {
  const size_t num_images = scene.NumImages();
  const size_t num_training = std::min<size_t>(num_images, options.max_vlad_training_images);
  // Evenly spaced images cover the whole map rather than its first streets.
  const auto spread = [num_images](size_t t, size_t count) { return t * num_images / count; };
  std::vector<DescriptorMatrix> training;
  training.reserve(num_training);
  for (size_t t = 0; t < num_training; ++t) {
    training.push_back(features.Read(scene.images[spread(t, num_training)].name).descriptors);
  }
  const size_t num_whitening = std::min<size_t>(num_images, options.max_vlad_whitening_images);
  // The whitening of a city's thousands of images takes minutes, read image by image.
  if (options.vlad.whitened_dim > 0) {
    spdlog::info("vlad: codebook from {} images, whitening to at most {} dimensions from {} images",
                 num_training, options.vlad.whitened_dim, num_whitening);
  }
  return VladEncoder::Train(
      training, num_whitening,
      [&](size_t t) {
        return features.Read(scene.images[spread(t, num_whitening)].name).descriptors;
      },
      options.vlad);
}

GlobalDescriptorMatrix EncodeDatabase(const Scene& scene, const FeatureReader& features,
                                      const VladEncoder& vlad, const MapBuildOptions& options) {
  const size_t num_images = scene.NumImages();
  GlobalDescriptorMatrix descriptors(num_images, vlad.output_dim());
  ProgressBar progress(
      "vlad", num_images,
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  std::vector<DescriptorMatrix> batch;
  for (size_t begin = 0; begin < num_images; begin += kVladBatchSize) {
    const size_t end = std::min(num_images, begin + kVladBatchSize);
    batch.clear();
    for (size_t i = begin; i < end; ++i) {
      batch.push_back(features.Read(scene.images[i].name).descriptors);
    }
    ParallelFor(end - begin, options.vlad.num_threads, [&](size_t lo, size_t hi) {
      for (size_t i = lo; i < hi; ++i) {
        descriptors.row(begin + i) = vlad.Encode(batch[i]).transpose();
      }
    });
    progress.Advance(end - begin);
  }
  return descriptors;
}

uint64_t DirectoryBytes(const fs::path& dir) {
  uint64_t bytes = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.is_regular_file()) bytes += entry.file_size();
  }
  return bytes;
}

// The retrieval stage's parts: the VLAD encoder (absent with external global descriptors) and
// one global descriptor per database image.
struct RetrievalParts {
  std::optional<VladEncoder> vlad;
  GlobalDescriptorMatrix global_descriptors;
};

RetrievalParts BuildRetrieval(const MapBuildInputs& inputs, const MapBuildOptions& options,
                              const Scene& scene, const FeatureReader& features) {
  RetrievalParts parts;
  if (inputs.global_features) {
    parts.global_descriptors = ExternalGlobalDescriptors(scene, *inputs.global_features);
  } else {
    parts.vlad = TrainVlad(scene, features, options);
    parts.global_descriptors = EncodeDatabase(scene, features, *parts.vlad, options);
  }
  return parts;
}

void WriteMetadata(const MapBuildInputs& inputs, const MapBuildOptions& options, const Scene& scene,
                   int64_t descriptor_dim, const LabelTree& tree, const RetrievalParts& retrieval,
                   nlohmann::json& metadata) {
  const bool vlad = retrieval.vlad.has_value();
  const GlobalDescriptorMatrix& global_descriptors = retrieval.global_descriptors;
  metadata[map_metadata::kDescriptorDim] = descriptor_dim;
  metadata[map_metadata::kNumImages] = scene.NumImages();
  metadata[map_metadata::kNumPoints] = scene.NumPoints();
  metadata[map_metadata::kNumObservations] = scene.NumObservations();
  metadata[map_metadata::kNumCameras] = scene.cameras.size();
  metadata[map_metadata::kLabelTree] = {{"levels", tree.levels()},
                                        {"branching", tree.branching()},
                                        {"num_nodes", tree.NumNodes()},
                                        {"kmeans_iterations", options.label_tree.kmeans_iterations},
                                        {"seed", options.label_tree.seed}};
  nlohmann::json retrieval_json = {{"global_descriptor", vlad ? "vlad" : "external"},
                                   {"global_descriptor_dim", global_descriptors.cols()},
                                   {"index", IndexTypeName(options.global_index.type)}};
  if (vlad) {
    retrieval_json["vlad"] = {
        {"num_words", options.vlad.num_words},
        {"whitened_dim", options.vlad.whitened_dim},
        {"power_normalization", options.vlad.power_normalization},
        {"training_images", std::min<size_t>(scene.NumImages(), options.max_vlad_training_images)},
        {"whitening_images",
         std::min<size_t>(scene.NumImages(), options.max_vlad_whitening_images)},
        {"seed", options.vlad.seed}};
  }
  metadata[map_metadata::kRetrieval] = retrieval_json;
  metadata[map_metadata::kSources] = {{"model", fs::absolute(inputs.model_dir).string()},
                                      {"features", fs::absolute(inputs.features).string()}};
  if (inputs.global_features) {
    metadata[map_metadata::kSources]["global_features"] =
        fs::absolute(*inputs.global_features).string();
  }
}

}  // namespace

void MapBuildOptions::Check() const {
  label_tree.Check();
  vlad.Check();
  global_index.Check();
  join.Check();
  THROW_CHECK_MSG(max_vlad_training_images >= 1, "max_vlad_training_images must be >= 1 (got {})",
                  max_vlad_training_images);
  THROW_CHECK_MSG(max_vlad_whitening_images >= 1, "max_vlad_whitening_images must be >= 1 (got {})",
                  max_vlad_whitening_images);
}

MapBuildSummary BuildMap(const MapBuildInputs& inputs, const MapBuildOptions& options,
                         const fs::path& bundle_dir) {
  options.Check();
  Timer total;
  MapBuildSummary summary;

  Timer stage;
  Reconstruction reconstruction = ReadColmapModel(inputs.model_dir);
  THROW_CHECK_MSG(!reconstruction.images.empty() && !reconstruction.points3D.empty(),
                  "COLMAP model {} has {} images and {} points; a map needs both",
                  inputs.model_dir.string(), reconstruction.images.size(),
                  reconstruction.points3D.size());
  const std::unique_ptr<FeatureReader> features = OpenFeatureReader(inputs.features);
  // The join streams: each image's observed descriptors go to the observations blob as they are
  // read, so the map's descriptors (4.7 GB for the aachen preset in floats) are never held; only
  // each point's sum of them is (1.6 GB there), for the points' descriptors.
  const Scene scene = Scene::FromReconstruction(reconstruction, ObservationIndices(reconstruction));
  MapBundleWriter writer(bundle_dir);
  int64_t descriptor_dim = 0;
  PointDescriptorAccumulator point_sums(scene.NumPoints());
  writer.AddBlob(map_blobs::kObservations, [&](std::ostream& s) {
    std::optional<SceneObservationsWriter> blob;
    size_t joined_rows = 0;
    descriptor_dim = ForEachJoinedImage(
        reconstruction, *features, options.join,
        [&](const Image&, const ImageFeatures& image_features,
            const std::vector<point2D_t>& keypoint_rows) {
          if (!blob) blob.emplace(s, scene, image_features.Dimension());
          const DescriptorMatrix rows = image_features.descriptors(keypoint_rows, Eigen::all);
          blob->Append(rows);
          // Observations come in the scene's order (ObservationIndices).
          point_sums.Add(rows, scene.observation_point_indices.data() + joined_rows);
          joined_rows += keypoint_rows.size();
        });
    if (!blob) blob.emplace(s, scene, 0);
    blob->Finish();
  });
  writer.AddBlob(map_blobs::kPointDescriptors,
                 [&](std::ostream& s) { point_sums.Finish().Write(s); });
  // Its 2D points are most of what it holds, and the scene has kept the rest.
  reconstruction = Reconstruction();
  summary.seconds_join = stage.ElapsedSeconds();
  spdlog::info("scene: {} images, {} points, {} observations of dimension {} ({:.1f} s)",
               scene.NumImages(), scene.NumPoints(), scene.NumObservations(), descriptor_dim,
               summary.seconds_join);

  stage.Restart();
  LabelTreeOptions tree_options = options.label_tree;
  tree_options.show_progress = options.show_progress;
  const LabelTree tree = LabelTree::Build(scene.points, tree_options);
  const Visibility visibility = Visibility::FromObservations(scene.NumImages(), scene.NumPoints(),
                                                             scene.observation_image_indices,
                                                             scene.observation_point_indices);
  summary.seconds_label_tree = stage.ElapsedSeconds();
  spdlog::info("label tree: {} levels, branching {}, {} nodes ({:.1f} s)", tree.levels(),
               tree.branching(), tree.NumNodes(), summary.seconds_label_tree);

  stage.Restart();
  const RetrievalParts retrieval = BuildRetrieval(inputs, options, scene, *features);
  const GlobalIndex index = GlobalIndex::Build(retrieval.global_descriptors, options.global_index);
  summary.seconds_retrieval = stage.ElapsedSeconds();
  spdlog::info("retrieval: {} global descriptors of dimension {} ({:.1f} s)",
               retrieval.global_descriptors.rows(), retrieval.global_descriptors.cols(),
               summary.seconds_retrieval);

  stage.Restart();
  writer.AddBlob(map_blobs::kScene, [&](std::ostream& s) { WriteSceneGeometry(s, scene); });
  writer.AddBlob(map_blobs::kLabelTree, [&](std::ostream& s) { tree.Write(s); });
  writer.AddBlob(map_blobs::kVisibility, [&](std::ostream& s) { visibility.Write(s); });
  if (retrieval.vlad) {
    writer.AddBlob(map_blobs::kVlad, [&](std::ostream& s) { retrieval.vlad->Write(s); });
  }
  writer.AddBlob(map_blobs::kGlobalDescriptors,
                 [&](std::ostream& s) { WriteGlobalDescriptors(s, retrieval.global_descriptors); });
  writer.AddBlob(map_blobs::kGlobalIndex, [&](std::ostream& s) { index.Write(s); });

  WriteMetadata(inputs, options, scene, descriptor_dim, tree, retrieval, writer.metadata());
  writer.Commit();
  summary.seconds_write = stage.ElapsedSeconds();

  summary.num_images = scene.NumImages();
  summary.num_points = scene.NumPoints();
  summary.num_observations = scene.NumObservations();
  summary.descriptor_dim = static_cast<int>(descriptor_dim);
  summary.global_descriptor_dim = static_cast<int>(retrieval.global_descriptors.cols());
  summary.num_tree_nodes = tree.NumNodes();
  summary.bundle_bytes = DirectoryBytes(bundle_dir);
  summary.seconds_total = total.ElapsedSeconds();
  return summary;
}

}  // namespace hscloc
