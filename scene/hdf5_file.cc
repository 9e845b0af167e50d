#include "scene/hdf5_file.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "util/check.h"
#include "util/half.h"

namespace hscloc::hdf5 {
namespace {

// hloc files nest a group per '/' of an image name; a deeper tree is a corrupt or cyclic file.
constexpr int kMaxGroupDepth = 64;
// No image of any real feature set holds this many values in one dataset; a larger shape is a
// corrupt header, and rejecting it keeps a bad file from turning into a huge allocation.
constexpr hsize_t kMaxDatasetElements = hsize_t{1} << 31;

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

}  // namespace

void SilenceHdf5Errors() {
  thread_local bool silenced = false;
  if (!silenced) {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    silenced = true;
  }
}

FloatEncoding::FloatEncoding(H5FloatPrecision precision, const std::filesystem::path& path)
    : precision_(precision) {
  if (precision == H5FloatPrecision::kFloat32) {
    file_type_ = CheckedHandle(H5Tcopy(H5T_IEEE_F32LE), H5Tclose, path, "copying float32");
  } else {
    file_type_ = MakeHalfType(H5T_IEEE_F32LE, path);
    memory_type_ = MakeHalfType(H5T_NATIVE_FLOAT, path);
  }
}

std::optional<size_t> FloatEncoding::FirstUnrepresentable(const float* values, size_t count) const {
  // Half's largest finite value is 65504; from 65520 on, rounding gives infinity.
  const float limit =
      precision_ == H5FloatPrecision::kFloat16 ? 65520.f : std::numeric_limits<float>::infinity();
  for (size_t i = 0; i < count; ++i) {
    if (!(std::abs(values[i]) < limit)) return i;
  }
  return std::nullopt;
}

Handle FloatEncoding::MakeHalfType(hid_t float32_type, const std::filesystem::path& path) {
  Handle type = CheckedHandle(H5Tcopy(float32_type), H5Tclose, path, "copying float32");
  if (H5Tset_fields(type.get(), 15, 10, 5, 0, 10) < 0 || H5Tset_size(type.get(), 2) < 0 ||
      H5Tset_ebias(type.get(), 15) < 0) {
    ThrowHdf5Error(path, "building the float16 type");
  }
  return type;
}

[[noreturn]] void ThrowHdf5Error(const std::filesystem::path& path, const std::string& what) {
  ThrowInvalidArgument("HDF5 file {}: {} ({})", path.string(), what, Hdf5ErrorDetail());
}

Handle CheckedHandle(hid_t id, Handle::Closer close, const std::filesystem::path& path,
                     const std::string& what) {
  if (id < 0) ThrowHdf5Error(path, what);
  return Handle(id, close);
}

bool LinkExists(hid_t group, const std::string& name) {
  return H5Lexists(group, name.c_str(), H5P_DEFAULT) > 0;
}

// Names (relative to the file root, '/'-joined) of the groups under `group` that hold a dataset
// called `marker`.
std::vector<std::string> FindGroupsWith(hid_t group, const std::string& prefix, const char* marker,
                                        const std::filesystem::path& path, int depth) {
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

std::string ShapeString(const std::vector<hsize_t>& shape) {
  std::string text;
  for (size_t i = 0; i < shape.size(); ++i) text += (i ? " x " : "") + std::to_string(shape[i]);
  return shape.empty() ? "scalar" : text;
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

}  // namespace hscloc::hdf5
