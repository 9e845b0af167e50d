// One descriptor per map point, for matching a query without the observations: the unit mean of
// the point's observed unit descriptors (its class mean), at 8 bits with a scale per point. On
// the aachen preset that is 1.5 M points x 256 bytes, where the observations take 2.4 GB at half
// precision, so a serving map can hold it. The localizer matches against it where the network
// leaves a query without a pose (localization/localizer.h, LocalizerOptions::
// nearest_point_candidates).
#pragma once

#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

#include "scene/features.h"

namespace hscloc {

class PointDescriptors {
 public:
  PointDescriptors() = default;

  size_t NumPoints() const { return scales_.size(); }
  int64_t Dimension() const { return dimension_; }
  bool empty() const { return scales_.empty(); }

  // The unit rows of `points`, in that order (a point never observed is a zero row). Throws
  // std::invalid_argument for an index past NumPoints().
  DescriptorMatrix UnitRows(const uint32_t* points, size_t count) const;
  // The 8-bit codes of `points`, in that order, row-major (count x Dimension()): each point's
  // direction, as UnitRows decodes it (a point never observed: zeros). Throws
  // std::invalid_argument for an index past NumPoints().
  std::vector<int8_t> CodeRows(const uint32_t* points, size_t count) const;

  // Little-endian: magic "HSCP", version, point count, dimension, each point's scale (float32),
  // then each point's codes (int8, row-major).
  void Write(std::ostream& stream) const;
  // Throws std::invalid_argument naming `source` when the data is truncated or inconsistent.
  static PointDescriptors Read(std::istream& stream, const std::string& source);

  bool operator==(const PointDescriptors& other) const;

 private:
  friend class PointDescriptorAccumulator;

  int64_t dimension_ = 0;
  std::vector<float> scales_;  // per point: the value of code 1
  std::vector<int8_t> codes_;  // NumPoints() x dimension_
};

// Sums each point's unit descriptors as the observations stream in (the map builder reads them
// image by image), then quantizes their directions. Holds NumPoints x D floats meanwhile.
class PointDescriptorAccumulator {
 public:
  explicit PointDescriptorAccumulator(size_t num_points);

  // Adds descriptor row i (any scale; it counts as its unit row) to point point_indices[i]. The
  // first call sets the dimension; throws std::invalid_argument when a later one differs or a
  // point index is out of range.
  void Add(const DescriptorMatrix& descriptors, const uint32_t* point_indices);
  // The unit mean of each point's rows at 8 bits; the accumulator is empty afterwards.
  PointDescriptors Finish();

 private:
  size_t num_points_;
  int64_t dimension_ = 0;
  std::vector<float> sums_;
};

}  // namespace hscloc
