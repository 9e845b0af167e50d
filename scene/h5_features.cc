#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <optional>
#include <set>

#include "scene/feature_io.h"
#include "util/check.h"
#include "util/half.h"

namespace hscloc {
namespace {

// hloc stores the centre of the top-left pixel at (0, 0), COLMAP at (0.5, 0.5).
constexpr float kHlocToColmapShiftPx = 0.5f;
// hloc files nest a group per '/' of an image name; a deeper tree is a corrupt or cyclic file.
constexpr int kMaxGroupDepth = 64;
// No image of any real feature set holds this many values in one dataset; a larger shape is a
// corrupt header, and rejecting it keeps a bad file from turning into a huge allocation.
constexpr hsize_t kMaxDatasetElements = hsize_t{1} << 31;

// HDF5 prints its error stack to stderr by default; errors here become exceptions instead. The
// setting is per thread in the thread-safe HDF5 build, hence once per thread.
void SilenceHdf5Errors() {
  thread_local bool silenced = false;
  if (!silenced) {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    silenced = true;
  }
}

// The innermost description on HDF5's error stack (the most specific one, e.g. "truncated
// file: eof = ..."), then clears the stack.
std::string Hdf5ErrorDetail() {
  std::string detail;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_DOWNWARD,
      [](unsigned, const H5E_error2_t* error, void* data) -> herr_t {
        if (error->desc != nullptr && error->desc[0] != '\0') {
          *static_cast<std::string*>(data) = error->desc;
        }
        return 0;
      },
      &detail);
  H5Eclear2(H5E_DEFAULT);
  return detail.empty() ? "unknown HDF5 error" : detail;
}

[[noreturn]] void ThrowHdf5Error(const std::filesystem::path& path, const std::string& what) {
  ThrowInvalidArgument("HDF5 file {}: {} ({})", path.string(), what, Hdf5ErrorDetail());
}

// Owns an HDF5 identifier and closes it with the matching H5?close.
class Handle {
 public:
  using Closer = herr_t (*)(hid_t);
  Handle() = default;
  Handle(hid_t id, Closer close) : id_(id), close_(close) {}
  Handle(Handle&& other) noexcept : id_(other.id_), close_(other.close_) { other.id_ = -1; }
  Handle& operator=(Handle&& other) noexcept {
    std::swap(id_, other.id_);
    std::swap(close_, other.close_);
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { Reset(); }

  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  // Closes now; false when HDF5 reports a failure (e.g. a file that cannot be flushed).
  bool Reset() {
    const bool ok = id_ < 0 || close_(id_) >= 0;
    id_ = -1;
    return ok;
  }

 private:
  hid_t id_ = -1;
  Closer close_ = nullptr;
};

Handle CheckedHandle(hid_t id, Handle::Closer close, const std::filesystem::path& path,
                     const std::string& what) {
  if (id < 0) ThrowHdf5Error(path, what);
  return Handle(id, close);
}

// HDF5 1.10's own float32 -> float16 conversion gets the exponent wrong by one when rounding
// carries into it (a value just below 0.125 becomes 0.0625; h5py issue #819), so writes convert
// with FloatToHalfBits and never ask HDF5 to narrow. Widening on reads is exact.

// How floats are stored: float32, or float16 laid out as h5py defines it (HDF5 1.10 has no
// predefined half type).
class FloatEncoding {
 public:
  FloatEncoding(H5FloatPrecision precision, const std::filesystem::path& path)
      : precision_(precision) {
    if (precision == H5FloatPrecision::kFloat32) {
      file_type_ = CheckedHandle(H5Tcopy(H5T_IEEE_F32LE), H5Tclose, path, "copying float32");
    } else {
      file_type_ = MakeHalfType(H5T_IEEE_F32LE, path);
      memory_type_ = MakeHalfType(H5T_NATIVE_FLOAT, path);
    }
  }

  // The first of `values` that is not finite or, in float16, rounds to infinity.
  std::optional<size_t> FirstUnrepresentable(const float* values, size_t count) const {
    // Half's largest finite value is 65504; from 65520 on, rounding gives infinity.
    const float limit =
        precision_ == H5FloatPrecision::kFloat16 ? 65520.f : std::numeric_limits<float>::infinity();
    for (size_t i = 0; i < count; ++i) {
      if (!(std::abs(values[i]) < limit)) return i;
    }
    return std::nullopt;
  }

  void Write(hid_t group, const char* dataset_name, const std::vector<hsize_t>& shape,
             const float* values, const std::filesystem::path& path,
             const std::string& where) const;

 private:
  static Handle MakeHalfType(hid_t float32_type, const std::filesystem::path& path) {
    Handle type = CheckedHandle(H5Tcopy(float32_type), H5Tclose, path, "copying float32");
    if (H5Tset_fields(type.get(), 15, 10, 5, 0, 10) < 0 || H5Tset_size(type.get(), 2) < 0 ||
        H5Tset_ebias(type.get(), 15) < 0) {
      ThrowHdf5Error(path, "building the float16 type");
    }
    return type;
  }

  H5FloatPrecision precision_;
  Handle file_type_;
  Handle memory_type_;  // float16 only; float32 is written from H5T_NATIVE_FLOAT
};

bool LinkExists(hid_t group, const std::string& name) {
  return H5Lexists(group, name.c_str(), H5P_DEFAULT) > 0;
}

// Names (relative to the file root, '/'-joined) of the groups under `group` that hold a dataset
// called `marker`.
std::vector<std::string> FindGroupsWith(hid_t group, const std::string& prefix, const char* marker,
                                        const std::filesystem::path& path, int depth = 0) {
  if (depth > kMaxGroupDepth) {
    ThrowInvalidArgument("HDF5 file {}: groups nested deeper than {} at '{}'", path.string(),
                         kMaxGroupDepth, prefix);
  }
  H5G_info_t info;
  if (H5Gget_info(group, &info) < 0) ThrowHdf5Error(path, "listing group '" + prefix + "'");
  std::vector<std::string> found;
  for (hsize_t i = 0; i < info.nlinks; ++i) {
    const ssize_t length =
        H5Lget_name_by_idx(group, ".", H5_INDEX_NAME, H5_ITER_INC, i, nullptr, 0, H5P_DEFAULT);
    if (length < 0) ThrowHdf5Error(path, "listing group '" + prefix + "'");
    std::string name(length, '\0');
    H5Lget_name_by_idx(group, ".", H5_INDEX_NAME, H5_ITER_INC, i, name.data(), length + 1,
                       H5P_DEFAULT);
    const std::string full_name = prefix.empty() ? name : prefix + "/" + name;
    Handle object = CheckedHandle(H5Oopen(group, name.c_str(), H5P_DEFAULT), H5Oclose, path,
                                  "opening '" + full_name + "'");
    const H5I_type_t type = H5Iget_type(object.get());
    if (type == H5I_DATASET && name == marker && !prefix.empty()) {
      found.push_back(prefix);
    } else if (type == H5I_GROUP) {
      std::vector<std::string> below =
          FindGroupsWith(object.get(), full_name, marker, path, depth + 1);
      found.insert(found.end(), below.begin(), below.end());
    }
  }
  return found;
}

// A dataset read as float whatever its stored numeric type (HDF5 converts).
struct FloatArray {
  std::vector<hsize_t> shape;
  std::vector<float> values;  // row-major
};

std::string ShapeString(const std::vector<hsize_t>& shape) {
  std::string text;
  for (size_t i = 0; i < shape.size(); ++i) text += (i ? " x " : "") + std::to_string(shape[i]);
  return shape.empty() ? "scalar" : text;
}

// nullopt when the group has no such dataset. `where` names the record in messages.
// True for the float16 layout h5py and hloc write: IEEE binary16, little-endian.
bool IsLittleEndianIeeeHalf(hid_t type) {
  if (H5Tget_class(type) != H5T_FLOAT || H5Tget_size(type) != 2 ||
      H5Tget_order(type) != H5T_ORDER_LE) {
    return false;
  }
  size_t sign_position, exponent_position, exponent_size, mantissa_position, mantissa_size;
  if (H5Tget_fields(type, &sign_position, &exponent_position, &exponent_size, &mantissa_position,
                    &mantissa_size) < 0) {
    return false;
  }
  return sign_position == 15 && exponent_position == 10 && exponent_size == 5 &&
         mantissa_position == 0 && mantissa_size == 10 && H5Tget_ebias(type) == 15;
}

std::optional<FloatArray> ReadFloatArray(hid_t group, const char* dataset_name,
                                         const std::filesystem::path& path,
                                         const std::string& where) {
  if (!LinkExists(group, dataset_name)) return std::nullopt;
  const std::string what = where + ", dataset " + dataset_name;
  Handle dataset =
      CheckedHandle(H5Dopen2(group, dataset_name, H5P_DEFAULT), H5Dclose, path, "opening " + what);
  Handle type =
      CheckedHandle(H5Dget_type(dataset.get()), H5Tclose, path, "reading type of " + what);
  const H5T_class_t type_class = H5Tget_class(type.get());
  if (type_class != H5T_FLOAT && type_class != H5T_INTEGER) {
    ThrowInvalidArgument("HDF5 file {}: {} is not numeric", path.string(), what);
  }
  Handle space =
      CheckedHandle(H5Dget_space(dataset.get()), H5Sclose, path, "reading shape of " + what);
  const int num_dims = H5Sget_simple_extent_ndims(space.get());
  if (num_dims < 0) ThrowHdf5Error(path, "reading shape of " + what);
  FloatArray array;
  array.shape.resize(num_dims);
  H5Sget_simple_extent_dims(space.get(), array.shape.data(), nullptr);
  hsize_t num_elements = 1;
  for (const hsize_t dim : array.shape) {
    if (dim > kMaxDatasetElements || num_elements * dim > kMaxDatasetElements) {
      ThrowInvalidArgument("HDF5 file {}: {} has an implausible shape {}", path.string(), what,
                           ShapeString(array.shape));
    }
    num_elements *= dim;
  }
  array.values.resize(num_elements);
  // HDF5 rejects a null buffer even for an empty selection.
  if (num_elements == 0) return array;
  if (IsLittleEndianIeeeHalf(type.get())) {
    // HDF5 widens halves through its generic soft conversion, about ten times slower than reading
    // the bits as they are stored and widening them here (exactly, as HDF5 would).
    std::vector<uint16_t> halves(num_elements);
    if (H5Dread(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, halves.data()) < 0) {
      ThrowHdf5Error(path, "reading " + what);
    }
    std::transform(halves.begin(), halves.end(), array.values.begin(), HalfBitsToFloat);
    return array;
  }
  if (H5Dread(dataset.get(), H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, array.values.data()) <
      0) {
    ThrowHdf5Error(path, "reading " + what);
  }
  return array;
}

std::optional<size_t> FirstNonFinite(const std::vector<float>& values) {
  for (size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) return i;
  }
  return std::nullopt;
}

void CheckImageName(const std::string& name, const std::filesystem::path& path) {
  if (name.empty() || name.front() == '/' || name.back() == '/' ||
      name.find("//") != std::string::npos) {
    ThrowInvalidArgument(
        "HDF5 file {}: image name '{}' cannot name a group (empty, or a leading, trailing or "
        "doubled '/')",
        path.string(), name);
  }
}

// Creation properties without modification times: HDF5 stamps objects by default, which would
// make two writes of the same features differ byte for byte.
Handle UntimedCreationProperties(hid_t property_class, const std::filesystem::path& path) {
  Handle properties =
      CheckedHandle(H5Pcreate(property_class), H5Pclose, path, "creating object properties");
  if (H5Pset_obj_track_times(properties.get(), false) < 0) {
    ThrowHdf5Error(path, "switching off object modification times");
  }
  return properties;
}

// The group of `name`, creating it and every missing group on its '/'-separated path.
Handle OpenOrCreateGroup(hid_t file, const std::string& name, const std::filesystem::path& path) {
  CheckImageName(name, path);
  Handle group = CheckedHandle(H5Gopen2(file, "/", H5P_DEFAULT), H5Gclose, path, "opening root");
  const Handle group_properties = UntimedCreationProperties(H5P_GROUP_CREATE, path);
  size_t begin = 0;
  while (begin <= name.size()) {
    const size_t end = std::min(name.find('/', begin), name.size());
    const std::string component = name.substr(begin, end - begin);
    const std::string so_far = name.substr(0, end);
    const hid_t id = LinkExists(group.get(), component)
                         ? H5Gopen2(group.get(), component.c_str(), H5P_DEFAULT)
                         : H5Gcreate2(group.get(), component.c_str(), H5P_DEFAULT,
                                      group_properties.get(), H5P_DEFAULT);
    group = CheckedHandle(id, H5Gclose, path, "creating group '" + so_far + "'");
    begin = end + 1;
  }
  return group;
}

void WriteDataset(hid_t group, const char* dataset_name, hid_t file_type, hid_t memory_type,
                  const std::vector<hsize_t>& shape, const void* data,
                  const std::filesystem::path& path, const std::string& where) {
  const std::string what = where + ", dataset " + dataset_name;
  Handle space =
      CheckedHandle(H5Screate_simple(static_cast<int>(shape.size()), shape.data(), nullptr),
                    H5Sclose, path, "creating the dataspace of " + what);
  const Handle dataset_properties = UntimedCreationProperties(H5P_DATASET_CREATE, path);
  Handle dataset = CheckedHandle(H5Dcreate2(group, dataset_name, file_type, space.get(),
                                            H5P_DEFAULT, dataset_properties.get(), H5P_DEFAULT),
                                 H5Dclose, path, "creating " + what);
  hsize_t num_elements = 1;
  for (const hsize_t dim : shape) num_elements *= dim;
  if (num_elements > 0 &&
      H5Dwrite(dataset.get(), memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0) {
    ThrowHdf5Error(path, "writing " + what);
  }
}

void FloatEncoding::Write(hid_t group, const char* dataset_name, const std::vector<hsize_t>& shape,
                          const float* values, const std::filesystem::path& path,
                          const std::string& where) const {
  hsize_t num_elements = 1;
  for (const hsize_t dim : shape) num_elements *= dim;
  if (precision_ == H5FloatPrecision::kFloat32) {
    WriteDataset(group, dataset_name, file_type_.get(), H5T_NATIVE_FLOAT, shape, values, path,
                 where);
    return;
  }
  std::vector<uint16_t> halves(num_elements);
  std::transform(values, values + num_elements, halves.begin(), FloatToHalfBits);
  WriteDataset(group, dataset_name, file_type_.get(), memory_type_.get(), shape, halves.data(),
               path, where);
}

Handle OpenForReading(const std::filesystem::path& path) {
  SilenceHdf5Errors();
  if (!std::filesystem::is_regular_file(path)) {
    ThrowInvalidArgument("HDF5 file {} does not exist or is not a file", path.string());
  }
  return CheckedHandle(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose, path,
                       "cannot open (not an HDF5 file, or truncated)");
}

Handle OpenForAppending(const std::filesystem::path& path) {
  SilenceHdf5Errors();
  return CheckedHandle(H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT), H5Fclose, path,
                       "cannot open for appending (not an HDF5 file, truncated, or read-only)");
}

Handle CreateForWriting(const std::filesystem::path& path) {
  SilenceHdf5Errors();
  // The file creation properties reach the root group, which must not carry a time either.
  const Handle file_properties = UntimedCreationProperties(H5P_FILE_CREATE, path);
  return CheckedHandle(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, file_properties.get(), H5P_DEFAULT),
                       H5Fclose, path, "cannot create");
}

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
    SilenceHdf5Errors();
    if (!HasImage(image_name)) {
      ThrowInvalidArgument("HDF5 file {}: no image '{}' (no group holding keypoints)",
                           path_.string(), image_name);
    }
    const std::string where = "image '" + image_name + "'";
    Handle group = CheckedHandle(H5Gopen2(file_.get(), image_name.c_str(), H5P_DEFAULT), H5Gclose,
                                 path_, "opening " + where);
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

  const std::filesystem::path& path() const override { return path_; }

 private:
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
