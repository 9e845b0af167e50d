#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <optional>
#include <set>

#include "scene/feature_io.h"
#include "scene/hdf5_file.h"
#include "util/check.h"
#include "util/half.h"

namespace hscloc {
namespace {

using hdf5::CheckedHandle;
using hdf5::CheckImageName;
using hdf5::CreateForWriting;
using hdf5::FindGroupsWith;
using hdf5::FirstNonFinite;
using hdf5::FloatArray;
using hdf5::FloatEncoding;
using hdf5::Handle;
using hdf5::kHlocToColmapShiftPx;
using hdf5::OpenForAppending;
using hdf5::OpenForReading;
using hdf5::OpenOrCreateGroup;
using hdf5::ReadFloatArray;
using hdf5::ShapeString;
using hdf5::SilenceHdf5Errors;
using hdf5::ThrowHdf5Error;
using hdf5::WriteDataset;

class H5Features : public FeatureReader {
 public:
  explicit H5Features(const std::filesystem::path& path)
      : path_(path), file_(OpenForReading(path)) {
    for (std::string& name : FindGroupsWith(file_.get(), "", "keypoints", path_)) {
      names_.insert(std::move(name));
    }
  }

  std::vector<std::string> ImageNames() const override {
    return std::vector<std::string>(names_.begin(), names_.end());
  }

  bool HasImage(const std::string& image_name) const override {
    return names_.count(image_name) > 0;
  }

  ImageFeatures Read(const std::string& image_name) const override {
    const std::string where = "image '" + image_name + "'";
    const Handle group = OpenImageGroup(image_name, where);
    const auto fail = [&](const char* dataset, const std::string& message) {
      ThrowInvalidArgument("HDF5 file {}: {}, dataset {}: {}", path_.string(), where, dataset,
                           message);
    };

    const std::optional<FloatArray> keypoints =
        ReadFloatArray(group.get(), "keypoints", path_, where);
    if (!keypoints) fail("keypoints", "missing");
    if (keypoints->shape.size() != 2 || keypoints->shape[1] != 2) {
      fail("keypoints", "shape " + ShapeString(keypoints->shape) + ", expected N x 2");
    }
    const auto num_keypoints = static_cast<int64_t>(keypoints->shape[0]);
    if (const auto bad = FirstNonFinite(keypoints->values)) {
      fail("keypoints", fmt::format("keypoint {} is not finite", *bad / 2));
    }

    const std::optional<FloatArray> descriptors =
        ReadFloatArray(group.get(), "descriptors", path_, where);
    if (!descriptors) fail("descriptors", "missing");
    if (descriptors->shape.size() != 2 ||
        static_cast<int64_t>(descriptors->shape[1]) != num_keypoints) {
      fail("descriptors", fmt::format("shape {}, expected D x {} (hloc stores one descriptor per "
                                      "column, one column per keypoint)",
                                      ShapeString(descriptors->shape), num_keypoints));
    }
    const auto dimension = static_cast<int64_t>(descriptors->shape[0]);
    if (const auto bad = FirstNonFinite(descriptors->values)) {
      fail("descriptors", fmt::format("descriptor of keypoint {} is not finite (dimension {})",
                                      *bad % num_keypoints, *bad / num_keypoints));
    }

    ImageFeatures features;
    features.keypoints =
        (Eigen::Map<const KeypointMatrix>(keypoints->values.data(), num_keypoints, 2).array() +
         kHlocToColmapShiftPx)
            .matrix();
    features.descriptors =
        Eigen::Map<const DescriptorMatrix>(descriptors->values.data(), dimension, num_keypoints)
            .transpose();

    if (const auto scores = ReadFloatArray(group.get(), "scores", path_, where)) {
      if (scores->shape.size() != 1 || static_cast<int64_t>(scores->shape[0]) != num_keypoints) {
        fail("scores",
             fmt::format("shape {}, expected {}", ShapeString(scores->shape), num_keypoints));
      }
      if (const auto bad = FirstNonFinite(scores->values)) {
        fail("scores", fmt::format("score of keypoint {} is not finite", *bad));
      }
      features.scores = Eigen::Map<const Eigen::VectorXf>(scores->values.data(), num_keypoints);
    }
    return features;
  }

  std::optional<PhotoSize> ImageSize(const std::string& image_name) const override {
    const std::string where = "image '" + image_name + "'";
    const Handle group = OpenImageGroup(image_name, where);
    const std::optional<FloatArray> size = ReadFloatArray(group.get(), "image_size", path_, where);
    if (!size) return std::nullopt;
    const auto whole_positive = [](float value) {
      return value >= 1 && value == std::floor(value);
    };
    if (size->shape != std::vector<hsize_t>{2} || !whole_positive(size->values[0]) ||
        !whole_positive(size->values[1])) {
      ThrowInvalidArgument(
          "HDF5 file {}: {}, dataset image_size: shape {}, expected 2 whole positive numbers "
          "(width, height)",
          path_.string(), where, ShapeString(size->shape));
    }
    return PhotoSize{static_cast<int64_t>(size->values[0]), static_cast<int64_t>(size->values[1])};
  }

  const std::filesystem::path& path() const override { return path_; }

 private:
  Handle OpenImageGroup(const std::string& image_name, const std::string& where) const {
    SilenceHdf5Errors();
    if (!HasImage(image_name)) {
      ThrowInvalidArgument("HDF5 file {}: no image '{}' (no group holding keypoints)",
                           path_.string(), image_name);
    }
    return CheckedHandle(H5Gopen2(file_.get(), image_name.c_str(), H5P_DEFAULT), H5Gclose, path_,
                         "opening " + where);
  }

  std::filesystem::path path_;
  Handle file_;
  std::set<std::string> names_;
};

}  // namespace

std::unique_ptr<FeatureReader> OpenH5Features(const std::filesystem::path& path) {
  return std::make_unique<H5Features>(path);
}

struct H5FeatureWriter::Impl {
  std::filesystem::path path;
  Handle file;
  std::unique_ptr<FloatEncoding> encoding;  // descriptors and scores
  std::set<std::string> written;
};

H5FeatureWriter::H5FeatureWriter(const std::filesystem::path& path, H5FloatPrecision precision,
                                 H5WriteMode mode)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  if (mode == H5WriteMode::kAppend && std::filesystem::exists(path)) {
    impl_->file = OpenForAppending(path);
    for (std::string& name : FindGroupsWith(impl_->file.get(), "", "keypoints", path)) {
      impl_->written.insert(std::move(name));
    }
  } else {
    impl_->file = CreateForWriting(path);
  }
  impl_->encoding = std::make_unique<FloatEncoding>(precision, path);
}

H5FeatureWriter::~H5FeatureWriter() {
  // A destructor cannot report a failed flush; Close() does.
  if (impl_->file.valid()) impl_->file.Reset();
}

void H5FeatureWriter::Write(const std::string& image_name, const ImageFeatures& features,
                            int64_t width, int64_t height) {
  SilenceHdf5Errors();
  const std::filesystem::path& path = impl_->path;
  const auto fail = [&](const std::string& message) {
    ThrowInvalidArgument("writing HDF5 file {}, image '{}': {}", path.string(), image_name,
                         message);
  };
  if (!impl_->file.valid()) fail("the writer is closed");
  CheckImageName(image_name, path);
  if (impl_->written.count(image_name) > 0) fail("written before");
  const int64_t num_keypoints = features.NumKeypoints();
  if (features.descriptors.rows() != num_keypoints) {
    fail(
        fmt::format("{} descriptors for {} keypoints", features.descriptors.rows(), num_keypoints));
  }
  if (num_keypoints > 0 && features.Dimension() == 0) fail("descriptors of dimension 0");
  if (features.scores.size() != 0 && features.scores.size() != num_keypoints) {
    fail(fmt::format("{} scores for {} keypoints", features.scores.size(), num_keypoints));
  }
  if (!features.keypoints.allFinite()) fail("non-finite keypoint");
  const FloatEncoding& encoding = *impl_->encoding;
  if (const auto bad =
          encoding.FirstUnrepresentable(features.descriptors.data(), features.descriptors.size())) {
    fail(fmt::format("descriptor value {} is not finite or out of the stored precision's range",
                     features.descriptors.data()[*bad]));
  }
  if (const auto bad =
          encoding.FirstUnrepresentable(features.scores.data(), features.scores.size())) {
    fail(fmt::format("score {} is not finite or out of the stored precision's range",
                     features.scores(*bad)));
  }
  if (width <= 0 || height <= 0) fail(fmt::format("image size {} x {}", width, height));

  Handle group = OpenOrCreateGroup(impl_->file.get(), image_name, path);
  const std::string where = "image '" + image_name + "'";
  const hsize_t n = num_keypoints;
  // Keypoints stay float32 even for float16 files: half precision spacing is 0.5 px from 512 px
  // and 1 px from 1024 px, too coarse for pose estimation.
  const KeypointMatrix keypoints = (features.keypoints.array() - kHlocToColmapShiftPx).matrix();
  WriteDataset(group.get(), "keypoints", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, {n, 2}, keypoints.data(),
               path, where);
  const DescriptorMatrix descriptors_by_column = features.descriptors.transpose();
  encoding.Write(group.get(), "descriptors", {static_cast<hsize_t>(features.Dimension()), n},
                 descriptors_by_column.data(), path, where);
  if (features.scores.size() > 0) {
    encoding.Write(group.get(), "scores", {n}, features.scores.data(), path, where);
  }
  const int64_t image_size[2] = {width, height};
  WriteDataset(group.get(), "image_size", H5T_STD_I64LE, H5T_NATIVE_INT64, {2}, image_size, path,
               where);
  impl_->written.insert(image_name);
}

bool H5FeatureWriter::HasImage(const std::string& image_name) const {
  return impl_->written.count(image_name) > 0;
}

void H5FeatureWriter::Close() {
  SilenceHdf5Errors();
  if (impl_->file.valid() && !impl_->file.Reset()) {
    ThrowHdf5Error(impl_->path, "closing (flushing) the file");
  }
}

std::unordered_map<std::string, Eigen::VectorXf> ReadH5GlobalDescriptors(
    const std::filesystem::path& path) {
  const Handle file = OpenForReading(path);
  std::unordered_map<std::string, Eigen::VectorXf> descriptors;
  std::string first_name;
  for (const std::string& name : FindGroupsWith(file.get(), "", "global_descriptor", path)) {
    const std::string where = "image '" + name + "'";
    Handle group = CheckedHandle(H5Gopen2(file.get(), name.c_str(), H5P_DEFAULT), H5Gclose, path,
                                 "opening " + where);
    const FloatArray array = *ReadFloatArray(group.get(), "global_descriptor", path, where);
    // hloc writes G; a leading batch dimension of 1 is accepted as well.
    const bool is_vector =
        array.shape.size() == 1 || (array.shape.size() == 2 && array.shape[0] == 1);
    if (!is_vector) {
      ThrowInvalidArgument("HDF5 file {}: {}, dataset global_descriptor: shape {}, expected G",
                           path.string(), where, ShapeString(array.shape));
    }
    if (const auto bad = FirstNonFinite(array.values)) {
      ThrowInvalidArgument("HDF5 file {}: {}, dataset global_descriptor: element {} not finite",
                           path.string(), where, *bad);
    }
    const auto dimension = static_cast<int64_t>(array.values.size());
    if (!descriptors.empty() && descriptors.at(first_name).size() != dimension) {
      ThrowInvalidArgument(
          "HDF5 file {}: global descriptor dimension {} of image '{}' differs from {} of image "
          "'{}'",
          path.string(), dimension, name, descriptors.at(first_name).size(), first_name);
    }
    if (descriptors.empty()) first_name = name;
    descriptors[name] = Eigen::Map<const Eigen::VectorXf>(array.values.data(), dimension);
  }
  return descriptors;
}

void WriteH5GlobalDescriptors(const std::filesystem::path& path,
                              const std::unordered_map<std::string, Eigen::VectorXf>& descriptors,
                              H5FloatPrecision precision) {
  // Sorted, so that the same descriptors always give the same file.
  const std::map<std::string, const Eigen::VectorXf*> sorted = [&] {
    std::map<std::string, const Eigen::VectorXf*> result;
    for (const auto& [name, descriptor] : descriptors) result[name] = &descriptor;
    return result;
  }();
  SilenceHdf5Errors();
  const FloatEncoding encoding(precision, path);
  for (const auto& [name, descriptor] : sorted) {
    CheckImageName(name, path);
    const Eigen::VectorXf& first = *sorted.begin()->second;
    if (descriptor->size() == 0 || descriptor->size() != first.size()) {
      ThrowInvalidArgument(
          "writing HDF5 file {}: global descriptor of image '{}' has dimension {}, image '{}' {}",
          path.string(), name, descriptor->size(), sorted.begin()->first, first.size());
    }
    if (const auto bad = encoding.FirstUnrepresentable(descriptor->data(), descriptor->size())) {
      ThrowInvalidArgument(
          "writing HDF5 file {}: global descriptor of image '{}': value {} is not finite or out "
          "of the stored precision's range",
          path.string(), name, (*descriptor)(*bad));
    }
  }
  Handle file = CreateForWriting(path);
  for (const auto& [name, descriptor] : sorted) {
    Handle group = OpenOrCreateGroup(file.get(), name, path);
    encoding.Write(group.get(), "global_descriptor", {static_cast<hsize_t>(descriptor->size())},
                   descriptor->data(), path, "image '" + name + "'");
  }
  if (!file.Reset()) ThrowHdf5Error(path, "closing (flushing) the file");
}

}  // namespace hscloc
