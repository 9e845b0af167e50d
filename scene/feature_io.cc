#include "scene/feature_io.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include "util/check.h"

namespace hscloc {

std::optional<PhotoSize> FeatureReader::ImageSize(const std::string& image_name) const {
  if (!HasImage(image_name)) {
    ThrowInvalidArgument("{}: no features of the image '{}'", path().string(), image_name);
  }
  return std::nullopt;
}

std::unique_ptr<FeatureReader> OpenFeatureReader(const std::filesystem::path& path) {
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension == ".db") return OpenColmapDatabaseFeatures(path);
  if (extension == ".h5" || extension == ".hdf5") return OpenH5Features(path);
  ThrowInvalidArgument(
      "feature file {}: unknown extension '{}'; accepted: .db (COLMAP database), .h5 or .hdf5 "
      "(hloc features)",
      path.string(), extension);
}

void JoinOptions::Check() const {
  THROW_CHECK_MSG(std::isfinite(max_keypoint_mismatch_px) && max_keypoint_mismatch_px >= 0,
                  "JoinOptions.max_keypoint_mismatch_px must be finite and >= 0, got {}",
                  max_keypoint_mismatch_px);
}

Observations ObservationIndices(const Reconstruction& reconstruction) {
  size_t num_observations = 0;
  for (const auto& [image_id, image] : reconstruction.images) {
    num_observations += std::count_if(image.points2D.begin(), image.points2D.end(),
                                      [](const Point2D& point) { return point.HasPoint3D(); });
  }
  Observations observations;
  observations.image_ids.reserve(num_observations);
  observations.keypoint_indices.reserve(num_observations);
  observations.point3D_ids.reserve(num_observations);
  for (const auto& [image_id, image] : reconstruction.images) {
    for (size_t point2D_idx = 0; point2D_idx < image.points2D.size(); ++point2D_idx) {
      const Point2D& point = image.points2D[point2D_idx];
      if (!point.HasPoint3D()) continue;
      observations.image_ids.push_back(image_id);
      observations.keypoint_indices.push_back(static_cast<point2D_t>(point2D_idx));
      observations.point3D_ids.push_back(point.point3D_id);
    }
  }
  return observations;
}

int64_t ForEachJoinedImage(
    const Reconstruction& reconstruction, const FeatureReader& features, const JoinOptions& options,
    const std::function<void(const Image& image, const ImageFeatures& image_features,
                             const std::vector<point2D_t>& keypoint_rows)>& visit) {
  options.Check();
  const std::string source = features.path().string();
  for (const auto& [image_id, image] : reconstruction.images) {
    if (!features.HasImage(image.name)) {
      ThrowInvalidArgument(
          "joining features {}: image '{}' (id {}) of the reconstruction has no "
          "features",
          source, image.name, image_id);
    }
  }

  const Image* first_image = nullptr;  // the image that fixed the descriptor dimension
  int64_t dimension = 0;
  std::vector<point2D_t> keypoint_rows;
  for (const auto& [image_id, image] : reconstruction.images) {
    const bool observes = std::any_of(image.points2D.begin(), image.points2D.end(),
                                      [](const Point2D& point) { return point.HasPoint3D(); });
    if (!observes) continue;
    // One image's features at a time, never all at once.
    const ImageFeatures image_features = features.Read(image.name);
    const int64_t num_keypoints = image_features.NumKeypoints();
    if (image_features.descriptors.rows() != num_keypoints) {
      ThrowInvalidArgument("joining features {}: image '{}' has {} descriptors for {} keypoints",
                           source, image.name, image_features.descriptors.rows(), num_keypoints);
    }
    if (first_image == nullptr) {
      first_image = &image;
      dimension = image_features.Dimension();
    } else if (image_features.Dimension() != dimension) {
      ThrowInvalidArgument(
          "joining features {}: descriptor dimension {} of image '{}' differs from {} of image "
          "'{}'",
          source, image_features.Dimension(), image.name, dimension, first_image->name);
    }

    keypoint_rows.clear();
    for (size_t point2D_idx = 0; point2D_idx < image.points2D.size(); ++point2D_idx) {
      const Point2D& point = image.points2D[point2D_idx];
      if (!point.HasPoint3D()) continue;
      if (static_cast<int64_t>(point2D_idx) >= num_keypoints) {
        ThrowInvalidArgument(
            "joining features {}: image '{}' (id {}), 2D point {} (3D point {}): only {} "
            "keypoints",
            source, image.name, image_id, point2D_idx, point.point3D_id, num_keypoints);
      }
      const Eigen::Vector2d keypoint = image_features.keypoints.row(point2D_idx).cast<double>();
      const double mismatch_px = (keypoint - point.xy).norm();
      if (!(mismatch_px <= options.max_keypoint_mismatch_px)) {
        ThrowInvalidArgument(
            "joining features {}: image '{}' (id {}), 2D point {} (3D point {}) at ({}, {}) is "
            "{} px from its keypoint ({}, {}); max_keypoint_mismatch_px is {}",
            source, image.name, image_id, point2D_idx, point.point3D_id, point.xy.x(), point.xy.y(),
            mismatch_px, keypoint.x(), keypoint.y(), options.max_keypoint_mismatch_px);
      }
      keypoint_rows.push_back(static_cast<point2D_t>(point2D_idx));
    }
    visit(image, image_features, keypoint_rows);
  }
  return dimension;
}

Observations JoinObservations(const Reconstruction& reconstruction, const FeatureReader& features,
                              const JoinOptions& options) {
  Observations observations = ObservationIndices(reconstruction);
  DescriptorMatrix& descriptors = observations.descriptors;
  Eigen::Index row = 0;
  ForEachJoinedImage(reconstruction, features, options,
                     [&](const Image&, const ImageFeatures& image_features,
                         const std::vector<point2D_t>& keypoint_rows) {
                       // Allocated once, at the first image, which fixes the dimension.
                       if (descriptors.size() == 0) {
                         descriptors.resize(static_cast<Eigen::Index>(observations.size()),
                                            image_features.Dimension());
                       }
                       for (const point2D_t keypoint : keypoint_rows) {
                         descriptors.row(row++) = image_features.descriptors.row(keypoint);
                       }
                     });
  return observations;
}

}  // namespace hscloc
