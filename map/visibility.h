// Which map points each database image observes, as a compressed sparse row table: the points of
// image i are point_indices[offsets[i] .. offsets[i+1]), sorted and unique. Membership is a
// binary search (O(log n)); memory is 4 bytes per (image, point) pair.
#pragma once

#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

namespace hscloc {

class Visibility {
 public:
  Visibility() = default;
  // From parallel arrays of (image index, point index) observations, in any order, duplicates
  // allowed. Throws when an index is out of range.
  static Visibility FromObservations(size_t num_images, size_t num_points,
                                     const std::vector<uint32_t>& image_indices,
                                     const std::vector<uint32_t>& point_indices);

  size_t NumImages() const { return offsets_.empty() ? 0 : offsets_.size() - 1; }
  size_t NumPoints() const { return num_points_; }
  size_t NumEntries() const { return point_indices_.size(); }

  // Throws when image_index is out of range; a point index out of range is simply not visible.
  bool IsVisible(uint32_t image_index, uint32_t point_index) const;
  // The sorted points of an image, as [begin, end).
  const uint32_t* PointsBegin(uint32_t image_index) const {
    return point_indices_.data() + offsets_[image_index];
  }
  const uint32_t* PointsEnd(uint32_t image_index) const {
    return point_indices_.data() + offsets_[image_index + 1];
  }
  size_t NumPointsOfImage(uint32_t image_index) const {
    return offsets_[image_index + 1] - offsets_[image_index];
  }

  // Little-endian: magic "HSCV", version, counts, the end offset of each image, the points.
  void Write(std::ostream& stream) const;
  // Throws std::invalid_argument naming `source` when the data is truncated or inconsistent
  // (offsets out of order, points of an image not sorted, unique and in range).
  static Visibility Read(std::istream& stream, const std::string& source);

  bool operator==(const Visibility& other) const;

 private:
  size_t num_points_ = 0;
  std::vector<uint64_t> offsets_;
  std::vector<uint32_t> point_indices_;
};

}  // namespace hscloc
