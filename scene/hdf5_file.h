// HDF5 access shared by the hloc feature files and their global descriptors (scene/h5_features.cc):
// owned identifiers, errors as exceptions naming the file, numeric datasets read as floats,
// float16 written as h5py lays it out, groups nested by '/' in image names. Internal to scene/.
#pragma once

#include <hdf5.h>

#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "scene/feature_io.h"

namespace hscloc::hdf5 {

// hloc stores the centre of the top-left pixel at (0, 0), COLMAP at (0.5, 0.5).
inline constexpr float kHlocToColmapShiftPx = 0.5f;

// HDF5 prints its error stack to stderr by default; errors here become exceptions instead. The
// setting is per thread in the thread-safe HDF5 build: call it on each thread before HDF5 work.
void SilenceHdf5Errors();
[[noreturn]] void ThrowHdf5Error(const std::filesystem::path& path, const std::string& what);

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
                     const std::string& what);

// HDF5 1.10's own float32 -> float16 conversion gets the exponent wrong by one when rounding
// carries into it (a value just below 0.125 becomes 0.0625; h5py issue #819), so writes convert
// with FloatToHalfBits and never ask HDF5 to narrow. Widening on reads is exact.

// How floats are stored: float32, or float16 laid out as h5py defines it (HDF5 1.10 has no
// predefined half type).
class FloatEncoding {
 public:
  FloatEncoding(H5FloatPrecision precision, const std::filesystem::path& path);
  // The first of `values` that is not finite or, in float16, rounds to infinity.
  std::optional<size_t> FirstUnrepresentable(const float* values, size_t count) const;
  void Write(hid_t group, const char* dataset_name, const std::vector<hsize_t>& shape,
             const float* values, const std::filesystem::path& path,
             const std::string& where) const;

 private:
  static Handle MakeHalfType(hid_t float32_type, const std::filesystem::path& path);

  H5FloatPrecision precision_;
  Handle file_type_;
  Handle memory_type_;  // float16 only; float32 is written from H5T_NATIVE_FLOAT
};

bool LinkExists(hid_t group, const std::string& name);
// Names (relative to the file root, '/'-joined) of the groups under `group` that hold a dataset
// called `marker`.
std::vector<std::string> FindGroupsWith(hid_t group, const std::string& prefix, const char* marker,
                                        const std::filesystem::path& path, int depth = 0);

// A dataset read as float whatever its stored numeric type (HDF5 converts).
struct FloatArray {
  std::vector<hsize_t> shape;
  std::vector<float> values;  // row-major
};

std::string ShapeString(const std::vector<hsize_t>& shape);
// nullopt when the group has no such dataset. `where` names the record in messages.
std::optional<FloatArray> ReadFloatArray(hid_t group, const char* dataset_name,
                                         const std::filesystem::path& path,
                                         const std::string& where);
std::optional<size_t> FirstNonFinite(const std::vector<float>& values);
void CheckImageName(const std::string& name, const std::filesystem::path& path);
// The group of `name`, creating it and every missing group on its '/'-separated path.
Handle OpenOrCreateGroup(hid_t file, const std::string& name, const std::filesystem::path& path);
void WriteDataset(hid_t group, const char* dataset_name, hid_t file_type, hid_t memory_type,
                  const std::vector<hsize_t>& shape, const void* data,
                  const std::filesystem::path& path, const std::string& where);

Handle OpenForReading(const std::filesystem::path& path);
Handle OpenForAppending(const std::filesystem::path& path);
Handle CreateForWriting(const std::filesystem::path& path);

}  // namespace hscloc::hdf5
