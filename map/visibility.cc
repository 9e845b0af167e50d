#include "map/visibility.h"

#include <algorithm>
#include <istream>
#include <limits>
#include <ostream>

#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

constexpr uint32_t kMagic = 0x56435348;  // "HSCV"
constexpr uint32_t kVersion = 1;

}  // namespace

Visibility Visibility::FromObservations(size_t num_images, size_t num_points,
                                        const std::vector<uint32_t>& image_indices,
                                        const std::vector<uint32_t>& point_indices) {
  if (image_indices.size() != point_indices.size()) {
    ThrowInvalidArgument("visibility: {} image indices but {} point indices", image_indices.size(),
                         point_indices.size());
  }
  if (num_points > uint64_t{std::numeric_limits<uint32_t>::max()} + 1) {
    ThrowInvalidArgument("visibility: {} points do not fit 32-bit point indices", num_points);
  }
  for (size_t i = 0; i < image_indices.size(); ++i) {
    if (image_indices[i] >= num_images || point_indices[i] >= num_points) {
      ThrowInvalidArgument(
          "visibility: observation {} (image {}, point {}) is out of range ({} images, {} points)",
          i, image_indices[i], point_indices[i], num_images, num_points);
    }
  }

  // Counting sort by image, then sort and deduplicate each image's points in place.
  Visibility visibility;
  visibility.num_points_ = num_points;
  std::vector<uint64_t> start(num_images + 1, 0);
  for (const uint32_t image : image_indices) ++start[image + 1];
  for (size_t i = 0; i < num_images; ++i) start[i + 1] += start[i];
  std::vector<uint32_t> grouped(image_indices.size());
  {
    std::vector<uint64_t> next(start.begin(), start.end() - 1);
    for (size_t i = 0; i < image_indices.size(); ++i) {
      grouped[next[image_indices[i]]++] = point_indices[i];
    }
  }
  visibility.offsets_.assign(num_images + 1, 0);
  uint64_t size = 0;
  for (size_t i = 0; i < num_images; ++i) {
    const auto begin = grouped.begin() + static_cast<std::ptrdiff_t>(start[i]);
    const auto end = grouped.begin() + static_cast<std::ptrdiff_t>(start[i + 1]);
    std::sort(begin, end);
    const auto unique_end = std::unique(begin, end);
    const auto destination = grouped.begin() + static_cast<std::ptrdiff_t>(size);
    std::move(begin, unique_end, destination);
    size += static_cast<uint64_t>(unique_end - begin);
    visibility.offsets_[i + 1] = size;
  }
  grouped.resize(size);
  grouped.shrink_to_fit();
  visibility.point_indices_ = std::move(grouped);
  return visibility;
}

bool Visibility::IsVisible(uint32_t image_index, uint32_t point_index) const {
  THROW_CHECK_LT(size_t{image_index}, NumImages());
  return std::binary_search(PointsBegin(image_index), PointsEnd(image_index), point_index);
}

void Visibility::Write(std::ostream& stream) const {
  WriteBinary(stream, kMagic);
  WriteBinary(stream, kVersion);
  WriteBinary<uint64_t>(stream, NumImages());
  WriteBinary<uint64_t>(stream, num_points_);
  WriteBinary<uint64_t>(stream, NumEntries());
  if (!offsets_.empty()) WriteBinaryArray(stream, offsets_.data() + 1, NumImages());
  WriteBinaryArray(stream, point_indices_.data(), point_indices_.size());
}

Visibility Visibility::Read(std::istream& stream, const std::string& source) {
  if (ReadBinary<uint32_t>(stream, source + ": magic") != kMagic) {
    ThrowInvalidArgument("{}: not an hscloc visibility table (wrong magic)", source);
  }
  const auto version = ReadBinary<uint32_t>(stream, source + ": version");
  if (version != kVersion) {
    ThrowInvalidArgument("{}: visibility version {} (this build reads version {})", source, version,
                         kVersion);
  }
  const auto num_images = ReadBinary<uint64_t>(stream, source + ": image count");
  const auto num_points = ReadBinary<uint64_t>(stream, source + ": point count");
  const auto num_entries = ReadBinary<uint64_t>(stream, source + ": entry count");
  if (num_points > uint64_t{std::numeric_limits<uint32_t>::max()} + 1 ||
      static_cast<unsigned __int128>(num_entries) >
          static_cast<unsigned __int128>(num_images) * num_points) {
    ThrowInvalidArgument("{}: impossible counts ({} images, {} points, {} entries)", source,
                         num_images, num_points, num_entries);
  }
  Visibility visibility;
  visibility.num_points_ = num_points;
  // The offsets' leading zero is implicit in the file.
  const std::vector<uint64_t> ends =
      ReadBinaryVector<uint64_t>(stream, num_images, source + ": offsets");
  visibility.offsets_.push_back(0);
  visibility.offsets_.insert(visibility.offsets_.end(), ends.begin(), ends.end());
  visibility.point_indices_ =
      ReadBinaryVector<uint32_t>(stream, num_entries, source + ": point indices");

  for (size_t i = 0; i < num_images; ++i) {
    const uint64_t begin = visibility.offsets_[i];
    const uint64_t end = visibility.offsets_[i + 1];
    if (end < begin || end > num_entries) {
      ThrowInvalidArgument("{}: offsets of image {} are inconsistent ({} .. {} of {})", source, i,
                           begin, end, num_entries);
    }
    for (uint64_t e = begin; e < end; ++e) {
      const uint32_t point = visibility.point_indices_[e];
      if (point >= num_points || (e > begin && point <= visibility.point_indices_[e - 1])) {
        ThrowInvalidArgument("{}: points of image {} are not sorted, unique and < {}", source, i,
                             num_points);
      }
    }
  }
  if (visibility.offsets_.back() != num_entries) {
    ThrowInvalidArgument("{}: the offsets cover {} of {} entries", source,
                         visibility.offsets_.back(), num_entries);
  }
  return visibility;
}

bool Visibility::operator==(const Visibility& other) const {
  // A default-constructed table has no offsets at all, one built for no images has {0}: both
  // hold no images.
  return num_points_ == other.num_points_ && NumImages() == other.NumImages() &&
         point_indices_ == other.point_indices_ && (NumImages() == 0 || offsets_ == other.offsets_);
}

}  // namespace hscloc
