// Reading and writing local features (COLMAP database.db, hloc-style .h5) and global descriptors
// (hloc .h5), and joining features with a reconstruction into observations.
//
// hloc .h5 layout: one group per image name (names may contain '/', i.e. nested groups) holding
// `keypoints` (N x 2), `descriptors` (D x N), optionally `scores` (N) and `image_size` (2), in
// float16 or float32; a global-descriptor file holds `global_descriptor` (G) per image group.
// hloc stores keypoints with the centre of the top-left pixel at (0, 0); readers and writers here
// convert to and from COLMAP's (0.5, 0.5) so that the rest of hscloc sees one convention: reading
// adds 0.5 px, writing subtracts it.
#pragma once

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "scene/features.h"
#include "scene/reconstruction.h"

namespace hscloc {

struct PhotoSize {
  int64_t width = 0;
  int64_t height = 0;
  bool operator==(const PhotoSize& other) const {
    return width == other.width && height == other.height;
  }
};

// Random access to the local features of a set of images, whatever the file format.
class FeatureReader {
 public:
  virtual ~FeatureReader() = default;
  // The names of all images with features, sorted.
  virtual std::vector<std::string> ImageNames() const = 0;
  virtual bool HasImage(const std::string& image_name) const = 0;
  // Throws std::invalid_argument naming the file and the image when the image is missing or its
  // records are malformed (wrong counts, truncated blobs, non-finite values).
  virtual ImageFeatures Read(const std::string& image_name) const = 0;
  // The photo's width and height in pixels when the file records them (hloc's `image_size`: the
  // photo's size before any resize); std::nullopt otherwise (a COLMAP database keeps it only on
  // the camera, and this default says so). Throws for a missing image or a malformed record.
  virtual std::optional<PhotoSize> ImageSize(const std::string& image_name) const;
  // The path this reader reads.
  virtual const std::filesystem::path& path() const = 0;
};

// Opens a COLMAP database (`.db`) or an hloc feature file (`.h5`, `.hdf5`) by its extension.
std::unique_ptr<FeatureReader> OpenFeatureReader(const std::filesystem::path& path);

// COLMAP database.db: keypoint blobs of 2, 4 or 6 float32 columns (x, y, ...), descriptors uint8
// (returned as float, unscaled).
std::unique_ptr<FeatureReader> OpenColmapDatabaseFeatures(const std::filesystem::path& path);
// hloc .h5 features: image groups are found recursively (any group holding `keypoints`);
// `descriptors` is required, `scores` optional; any numeric stored type is read as float. The
// file stays open while the reader lives.
std::unique_ptr<FeatureReader> OpenH5Features(const std::filesystem::path& path);

enum class H5FloatPrecision { kFloat16, kFloat32 };
// kCreate truncates the file; kAppend adds images to an existing file (created when missing).
enum class H5WriteMode { kCreate, kAppend };

// Writes an hloc feature file image by image (streaming: nothing is held back in memory).
// Close() or the destructor flushes it, and only Close() reports a failure to. `precision` applies
// to descriptors and scores; keypoints are always float32 (float16 spacing is 1 px from 1024 px
// on), image_size int64.
class H5FeatureWriter {
 public:
  H5FeatureWriter(const std::filesystem::path& path, H5FloatPrecision precision,
                  H5WriteMode mode = H5WriteMode::kCreate);
  ~H5FeatureWriter();
  H5FeatureWriter(const H5FeatureWriter&) = delete;
  H5FeatureWriter& operator=(const H5FeatureWriter&) = delete;

  // image_size: width, height in pixels. Throws when the name was written before, or when the
  // features are inconsistent (descriptor or score count, non-finite values).
  void Write(const std::string& image_name, const ImageFeatures& features, int64_t width,
             int64_t height);
  // Whether the file holds the image (written here, or before when appending).
  bool HasImage(const std::string& image_name) const;
  void Close();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Global descriptors (hloc `global_descriptor`, shape G; 1 x G is read too), by image name. All
// must have one dimension; non-finite values throw.
std::unordered_map<std::string, Eigen::VectorXf> ReadH5GlobalDescriptors(
    const std::filesystem::path& path);
void WriteH5GlobalDescriptors(const std::filesystem::path& path,
                              const std::unordered_map<std::string, Eigen::VectorXf>& descriptors,
                              H5FloatPrecision precision);

struct JoinOptions {
  // Largest distance, in pixels, between a model's 2D point and its feature keypoint.
  double max_keypoint_mismatch_px = 1e-3;
  void Check() const;
};

// Every 2D point with a 3D point in every image of the reconstruction gets its keypoint's
// descriptor (POINT2D_IDX == keypoint row). Throws std::invalid_argument naming the image and the
// point when an image has no features, a 2D point index exceeds the keypoint count, a keypoint is
// farther than max_keypoint_mismatch_px from its 2D point, or descriptor dimensions differ between
// images. Rows are ordered by image id, then 2D point index.
Observations JoinObservations(const Reconstruction& reconstruction, const FeatureReader& features,
                              const JoinOptions& options = {});

// The join without its descriptors, from the model alone (no feature is read): the image id,
// keypoint index and point3D id of every row JoinObservations would make, in its order.
Observations ObservationIndices(const Reconstruction& reconstruction);

// The join one image at a time, for a map too large to hold its descriptors: after the checks
// JoinObservations makes (each image's as it is read), calls `visit` with every image that
// observes a point, in JoinObservations' order, its features and the keypoint rows it
// contributes. Returns the descriptor dimension (0 when no image observes a point).
int64_t ForEachJoinedImage(
    const Reconstruction& reconstruction, const FeatureReader& features, const JoinOptions& options,
    const std::function<void(const Image& image, const ImageFeatures& image_features,
                             const std::vector<point2D_t>& keypoint_rows)>& visit);

}  // namespace hscloc
