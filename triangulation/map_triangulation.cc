#include "triangulation/map_triangulation.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <map>
#include <memory>
#include <set>

#include "scene/colmap_database_writer.h"
#include "scene/colmap_io.h"
#include "scene/feature_io.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// What matching keeps of every image; descriptors are kept from the first read when every image's
// fit in memory at once, and read again a chunk of pairs at a time otherwise.
struct ImageData {
  KeypointMatrix keypoints;
  PosedKeypoints posed;
};

ProgressBar::Display Display(bool show) {
  return show ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever;
}

// Every model image's features, checked against its camera, and its undistorted keypoints; their
// descriptors go into `descriptors` unless it is null.
std::map<image_t, ImageData> ReadImageFeatures(const Reconstruction& model,
                                               const FeatureReader& reader, bool show_progress,
                                               std::map<image_t, DescriptorMatrix>* descriptors) {
  std::vector<std::string> missing;
  for (const auto& [image_id, image] : model.images) {
    if (!reader.HasImage(image.name)) missing.push_back(image.name);
  }
  if (!missing.empty()) {
    ThrowInvalidArgument(
        "{} has no features for {} of the model's {} images: {}{}", reader.path().string(),
        missing.size(), model.images.size(),
        fmt::join(missing.begin(), missing.begin() + std::min<size_t>(5, missing.size()), ", "),
        missing.size() > 5 ? ", ..." : "");
  }
  std::map<image_t, ImageData> images;
  ProgressBar progress("reading features", model.images.size(), Display(show_progress));
  int64_t dimension = -1;
  for (const auto& [image_id, image] : model.images) {
    const ImageFeatures features = reader.Read(image.name);
    const Camera& camera = model.cameras.at(image.camera_id);
    if (const std::optional<PhotoSize> size = reader.ImageSize(image.name);
        size && !(*size == PhotoSize{static_cast<int64_t>(camera.width),
                                     static_cast<int64_t>(camera.height)})) {
      ThrowInvalidArgument(
          "{}, image '{}': the features come from a photo of {} x {} pixels but its camera (camera "
          "{}) is {} x {}: extract the features from photos of the camera's size",
          reader.path().string(), image.name, size->width, size->height, camera.camera_id,
          camera.width, camera.height);
    }
    for (int64_t i = 0; i < features.NumKeypoints(); ++i) {
      const Eigen::Vector2d pixel = features.keypoints.row(i).cast<double>().transpose();
      if (!camera.IsInside(pixel)) {
        ThrowInvalidArgument(
            "{}, image '{}': keypoint {} at ({:.1f}, {:.1f}) px lies outside its camera's {} x {} "
            "pixels (camera {}): the features come from photos of another size than the model's",
            reader.path().string(), image.name, i, pixel.x(), pixel.y(), camera.width,
            camera.height, camera.camera_id);
      }
    }
    if (dimension >= 0 && features.Dimension() != dimension) {
      ThrowInvalidArgument("{}, image '{}': descriptors of dimension {}, the images before have {}",
                           reader.path().string(), image.name, features.Dimension(), dimension);
    }
    dimension = features.Dimension();
    ImageData data;
    data.keypoints = features.keypoints;
    if (descriptors != nullptr) descriptors->emplace(image_id, features.descriptors);
    data.posed = UndistortKeypoints(camera, image.cam_from_world, features.keypoints);
    images.emplace(image_id, std::move(data));
    progress.Advance();
  }
  return images;
}

struct PairMatches {
  std::vector<FeatureMatch> matches;
  VerifiedMatches verified;
};

// The pairs from `begin` on whose images number at most `max_images` (at least one pair).
size_t ChunkEnd(const std::vector<ImagePair>& pairs, size_t begin, int max_images,
                std::set<image_t>* images) {
  images->clear();
  size_t end = begin;
  for (; end < pairs.size(); ++end) {
    const size_t added =
        (images->count(pairs[end].image_id1) == 0) + (images->count(pairs[end].image_id2) == 0);
    if (end > begin && images->size() + added > static_cast<size_t>(max_images)) break;
    images->insert(pairs[end].image_id1);
    images->insert(pairs[end].image_id2);
  }
  return end;
}

// Pairs are matched in chunks whose images' descriptors fit in options.max_images_in_memory: a
// chunk's are read (those the previous chunk held, or `descriptors` brings, are kept), then its
// pairs matched on all cores. Pairs come sorted by their first image, and co-visible images are
// near each other, so most images are read once or twice.
std::vector<PairMatches> MatchPairs(const std::vector<ImagePair>& pairs,
                                    const Reconstruction& model,
                                    const std::map<image_t, ImageData>& images,
                                    std::map<image_t, DescriptorMatrix> descriptors,
                                    const FeatureReader& reader,
                                    const MapTriangulationOptions& options,
                                    MapTriangulationSummary* summary) {
  std::vector<PairMatches> results(pairs.size());
  ProgressBar progress("matching pairs", pairs.size(), Display(options.show_progress));
  std::set<image_t> chunk_images;
  for (size_t begin = 0; begin < pairs.size();) {
    const size_t end = ChunkEnd(pairs, begin, options.max_images_in_memory, &chunk_images);
    for (auto it = descriptors.begin(); it != descriptors.end();) {
      it = chunk_images.count(it->first) > 0 ? std::next(it) : descriptors.erase(it);
    }
    for (const image_t image_id : chunk_images) {
      if (descriptors.count(image_id) > 0) continue;
      descriptors.emplace(image_id, reader.Read(model.images.at(image_id).name).descriptors);
      ++summary->num_descriptor_reads;
    }
    ++summary->num_matching_chunks;
    ParallelFor(end - begin, options.num_threads, [&](size_t chunk_begin, size_t chunk_end) {
      for (size_t i = begin + chunk_begin; i < begin + chunk_end; ++i) {
        const ImagePair& pair = pairs[i];
        results[i].matches = MatchDescriptors(descriptors.at(pair.image_id1),
                                              descriptors.at(pair.image_id2), options.matching);
        results[i].verified =
            VerifyWithKnownPoses(images.at(pair.image_id1).posed, images.at(pair.image_id2).posed,
                                 results[i].matches, options.verification);
        progress.Advance();
      }
    });
    begin = end;
  }
  return results;
}

void WriteDatabase(const fs::path& path, const Reconstruction& model,
                   const std::map<image_t, ImageData>& images, const std::vector<ImagePair>& pairs,
                   const std::vector<PairMatches>& matches) {
  ColmapDatabaseWriter writer(path);
  for (const auto& [camera_id, camera] : model.cameras) writer.WriteCamera(camera);
  for (const auto& [image_id, image] : model.images) {
    writer.WriteImage(image_id, image.name, image.camera_id);
    writer.WriteKeypoints(image_id, images.at(image_id).keypoints);
  }
  for (size_t i = 0; i < pairs.size(); ++i) {
    const ImagePair& pair = pairs[i];
    writer.WriteMatches(pair.image_id1, pair.image_id2, matches[i].matches);
    if (!matches[i].verified.accepted) continue;
    const Rigid3d cam2_from_cam1 = images.at(pair.image_id2).posed.cam_from_world *
                                   images.at(pair.image_id1).posed.cam_from_world.Inverse();
    writer.WriteTwoViewGeometry(pair.image_id1, pair.image_id2, matches[i].verified.inliers,
                                cam2_from_cam1);
  }
  writer.Close();
}

// The model's cameras and poses without 2D or 3D points: COLMAP then takes each image's database
// keypoints as its 2D points.
Reconstruction PosesOnly(const Reconstruction& model) {
  Reconstruction poses;
  poses.cameras = model.cameras;
  poses.images = model.images;
  for (auto& [image_id, image] : poses.images) image.points2D.clear();
  return poses;
}

// The triangulated model must index the features' keypoints, or build-map could not join them.
void CheckIndexesKeypoints(const Reconstruction& triangulated,
                           const std::map<image_t, ImageData>& images, const fs::path& out_dir) {
  for (const auto& [image_id, image] : triangulated.images) {
    const auto it = images.find(image_id);
    if (it == images.end() ||
        static_cast<int64_t>(image.points2D.size()) != it->second.keypoints.rows()) {
      ThrowInvalidArgument(
          "COLMAP's model in {}: image '{}' (id {}) has {} 2D points for {} keypoints",
          out_dir.string(), image.name, image_id, image.points2D.size(),
          it == images.end() ? 0 : it->second.keypoints.rows());
    }
  }
}

}  // namespace

void MapTriangulationOptions::Check() const {
  if (max_images_in_memory < 2) {
    ThrowInvalidArgument("MapTriangulationOptions.max_images_in_memory must be at least 2 (got {})",
                         max_images_in_memory);
  }
  pairs.Check();
  matching.Check();
  verification.Check();
  colmap.Check();
}

MapTriangulationSummary TriangulateMap(const MapTriangulationInputs& inputs,
                                       const MapTriangulationOptions& options,
                                       const fs::path& out_dir) {
  options.Check();
  FindColmap(options.colmap);
  const Timer total;
  MapTriangulationSummary summary;
  const Reconstruction model = ReadColmapModel(inputs.model_dir);
  summary.num_images = static_cast<int64_t>(model.images.size());
  const std::unique_ptr<FeatureReader> reader = OpenFeatureReader(inputs.features);

  const std::vector<ImagePair> pairs = SelectCovisiblePairs(model, options.pairs);
  if (pairs.empty()) {
    ThrowInvalidArgument(
        "the model in {} has no two images that share a 3D point: no pair to "
        "match",
        inputs.model_dir.string());
  }
  // A model whose descriptors fit in memory at once keeps them from the first read.
  const bool all_in_memory =
      model.images.size() <= static_cast<size_t>(options.max_images_in_memory);
  std::map<image_t, DescriptorMatrix> descriptors;
  const std::map<image_t, ImageData> images = ReadImageFeatures(
      model, *reader, options.show_progress, all_in_memory ? &descriptors : nullptr);
  const std::vector<PairMatches> matches =
      MatchPairs(pairs, model, images, std::move(descriptors), *reader, options, &summary);
  summary.num_pairs = static_cast<int64_t>(pairs.size());
  for (const PairMatches& pair : matches) {
    summary.num_matches += static_cast<int64_t>(pair.matches.size());
    if (!pair.verified.accepted) continue;
    ++summary.num_verified_pairs;
    summary.num_verified_matches += static_cast<int64_t>(pair.verified.inliers.size());
  }
  summary.seconds_matching = total.ElapsedSeconds();
  spdlog::info(
      "{} pairs: {} matches, {} pairs verified with {} inlier matches; {} images' descriptors "
      "read again {} times, in {} chunks of at most {} images",
      summary.num_pairs, summary.num_matches, summary.num_verified_pairs,
      summary.num_verified_matches, images.size(), summary.num_descriptor_reads,
      summary.num_matching_chunks, options.max_images_in_memory);

  fs::create_directories(out_dir / MapTriangulationFiles::kWorkDir);
  for (const char* stale :
       {"cameras.bin", "images.bin", "points3D.bin", MapTriangulationFiles::kDatabase}) {
    fs::remove(out_dir / stale);
  }
  const fs::path database = out_dir / MapTriangulationFiles::kDatabase;
  WriteDatabase(database, model, images, pairs, matches);
  const fs::path input_model = out_dir / MapTriangulationFiles::kInputModel;
  WriteColmapModel(PosesOnly(model), input_model, ColmapFormat::kBinary);

  // COLMAP requires an image folder; without photos, an empty one leaves the points grey.
  fs::path image_dir = inputs.image_dir;
  if (image_dir.empty()) {
    image_dir = out_dir / MapTriangulationFiles::kNoImages;
    fs::create_directories(image_dir);
  }
  const Timer colmap;
  RunColmapPointTriangulator(
      {database, image_dir, input_model, out_dir, out_dir / MapTriangulationFiles::kColmapLog},
      options.colmap);
  summary.seconds_triangulation = colmap.ElapsedSeconds();

  const Reconstruction triangulated = ReadColmapModel(out_dir);
  CheckIndexesKeypoints(triangulated, images, out_dir);
  summary.num_registered_images = static_cast<int64_t>(triangulated.images.size());
  summary.num_points3D = static_cast<int64_t>(triangulated.points3D.size());
  summary.num_observations = static_cast<int64_t>(triangulated.NumObservations());
  if (summary.num_points3D > 0) {
    summary.mean_track_length = double(summary.num_observations) / summary.num_points3D;
    double error_sum = 0;
    for (const auto& [point3D_id, point] : triangulated.points3D) error_sum += point.error;
    summary.mean_reprojection_error_px = error_sum / summary.num_points3D;
  }
  summary.seconds_total = total.ElapsedSeconds();
  return summary;
}

}  // namespace hscloc
