#include "map/point_descriptors.h"

#include <algorithm>
#include <cmath>
#include <istream>
#include <ostream>

#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

constexpr uint32_t kMagic = 0x50435348;  // "HSCP"
constexpr uint32_t kVersion = 1;
constexpr float kLargestCode = 127.0f;

}  // namespace

DescriptorMatrix PointDescriptors::UnitRows(const uint32_t* points, size_t count) const {
  DescriptorMatrix rows(static_cast<Eigen::Index>(count), dimension_);
  for (size_t i = 0; i < count; ++i) {
    const uint32_t point = points[i];
    if (point >= NumPoints()) {
      ThrowInvalidArgument("point descriptors: point {} of {}", point, NumPoints());
    }
    const int8_t* codes = codes_.data() + static_cast<size_t>(point) * dimension_;
    const float scale = scales_[point];
    float* row = rows.row(static_cast<Eigen::Index>(i)).data();
    for (int64_t d = 0; d < dimension_; ++d) row[d] = scale * static_cast<float>(codes[d]);
  }
  // The codes round each value; renormalizing keeps dot products cosines.
  NormalizeRows(rows);
  return rows;
}

std::vector<int8_t> PointDescriptors::CodeRows(const uint32_t* points, size_t count) const {
  std::vector<int8_t> rows(count * static_cast<size_t>(dimension_));
  for (size_t i = 0; i < count; ++i) {
    if (points[i] >= NumPoints()) {
      ThrowInvalidArgument("point descriptors: point {} of {}", points[i], NumPoints());
    }
    std::copy_n(codes_.data() + static_cast<size_t>(points[i]) * dimension_, dimension_,
                rows.data() + i * dimension_);
  }
  return rows;
}

void PointDescriptors::Write(std::ostream& stream) const {
  WriteBinary(stream, kMagic);
  WriteBinary(stream, kVersion);
  WriteBinary<uint64_t>(stream, NumPoints());
  WriteBinary<uint64_t>(stream, static_cast<uint64_t>(dimension_));
  WriteBinaryArray(stream, scales_.data(), scales_.size());
  WriteBinaryArray(stream, codes_.data(), codes_.size());
}

PointDescriptors PointDescriptors::Read(std::istream& stream, const std::string& source) {
  if (ReadBinary<uint32_t>(stream, source + ": magic") != kMagic) {
    ThrowInvalidArgument("{}: not an hscloc point descriptor table (wrong magic)", source);
  }
  const auto version = ReadBinary<uint32_t>(stream, source + ": version");
  if (version != kVersion) {
    ThrowInvalidArgument("{}: point descriptor version {} (this build reads version {})", source,
                         version, kVersion);
  }
  const auto num_points = ReadBinary<uint64_t>(stream, source + ": point count");
  const auto dimension = ReadBinary<uint64_t>(stream, source + ": dimension");
  if (num_points > (uint64_t{1} << 32) || dimension > 65536 || (num_points > 0 && dimension == 0)) {
    ThrowInvalidArgument("{}: impossible counts ({} points of dimension {})", source, num_points,
                         dimension);
  }
  PointDescriptors descriptors;
  descriptors.dimension_ = static_cast<int64_t>(dimension);
  descriptors.scales_ = ReadBinaryVector<float>(stream, num_points, source + ": scales");
  for (size_t point = 0; point < descriptors.scales_.size(); ++point) {
    const float scale = descriptors.scales_[point];
    if (!std::isfinite(scale) || scale < 0) {
      ThrowInvalidArgument("{}: point {} has scale {}", source, point, scale);
    }
  }
  descriptors.codes_ = ReadBinaryVector<int8_t>(stream, num_points * dimension, source + ": codes");
  return descriptors;
}

bool PointDescriptors::operator==(const PointDescriptors& other) const {
  return dimension_ == other.dimension_ && scales_ == other.scales_ && codes_ == other.codes_;
}

PointDescriptorAccumulator::PointDescriptorAccumulator(size_t num_points)
    : num_points_(num_points) {}

void PointDescriptorAccumulator::Add(const DescriptorMatrix& descriptors,
                                     const uint32_t* point_indices) {
  if (descriptors.rows() == 0) return;
  if (dimension_ == 0) {
    THROW_CHECK_MSG(descriptors.cols() > 0, "point descriptors: rows of dimension 0");
    dimension_ = descriptors.cols();
    sums_.assign(num_points_ * static_cast<size_t>(dimension_), 0.0f);
  } else if (descriptors.cols() != dimension_) {
    ThrowInvalidArgument("point descriptors: rows of dimension {} after rows of dimension {}",
                         descriptors.cols(), dimension_);
  }
  for (Eigen::Index row = 0; row < descriptors.rows(); ++row) {
    const uint32_t point = point_indices[row];
    if (point >= num_points_) {
      ThrowInvalidArgument("point descriptors: point {} of {}", point, num_points_);
    }
    const float norm = descriptors.row(row).norm();
    if (norm == 0) continue;
    float* sum = sums_.data() + static_cast<size_t>(point) * dimension_;
    const float* values = descriptors.row(row).data();
    for (int64_t d = 0; d < dimension_; ++d) sum[d] += values[d] / norm;
  }
}

PointDescriptors PointDescriptorAccumulator::Finish() {
  PointDescriptors descriptors;
  descriptors.dimension_ = dimension_;
  descriptors.scales_.assign(dimension_ == 0 ? 0 : num_points_, 0.0f);
  descriptors.codes_.assign(descriptors.scales_.size() * static_cast<size_t>(dimension_), 0);
  for (size_t point = 0; point < descriptors.scales_.size(); ++point) {
    const float* sum = sums_.data() + point * dimension_;
    float largest = 0;
    for (int64_t d = 0; d < dimension_; ++d) largest = std::max(largest, std::abs(sum[d]));
    if (largest == 0) continue;
    // Only the direction matters (UnitRows renormalizes), so the sum is quantized as it is.
    descriptors.scales_[point] = largest / kLargestCode;
    int8_t* codes = descriptors.codes_.data() + point * dimension_;
    for (int64_t d = 0; d < dimension_; ++d) {
      codes[d] = static_cast<int8_t>(std::lround(sum[d] / largest * kLargestCode));
    }
  }
  sums_ = std::vector<float>();
  dimension_ = 0;
  return descriptors;
}

}  // namespace hscloc
