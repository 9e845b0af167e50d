// A bank of real descriptors: for every SfM track of some real photo sets, the descriptors of its
// views with the direction each view saw the point from, and, where the view's keypoint was found
// again in its photo under a night-like transform, the night descriptor there. The synthetic city
// draws its appearance from it (`hscloc synth --appearance real`), so that the spread within a
// point and the confusion between points are those of real descriptors.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "scene/features.h"

namespace hscloc {

using ViewDirectionMatrix = Eigen::Matrix<float, Eigen::Dynamic, 3, Eigen::RowMajor>;

// Where a view saw its point from, in the track's own frame: z along the track's mean viewing
// direction (from the point towards the cameras), x horizontal and y up-ward as far as the set's
// up direction (its cameras' mean up) allows. A direction of any point and its reference (a
// facade normal and the vertical, say) compares with it without a common world frame.
Eigen::Vector3f LocalViewDirection(const Eigen::Vector3d& direction,
                                   const Eigen::Vector3d& reference, const Eigen::Vector3d& up);
// The root-mean-square angular spread of `count` unit directions around their mean, from their
// sum: sqrt(1 - |sum / count|^2).
float DirectionSpread(const Eigen::Vector3d& sum_of_unit_directions, size_t count);
// Where a local direction lies among the directions it comes with: its (x, y) divided by their
// spread (as is when the spread is ~0). Two sets of views compare by it whatever their baselines:
// the view at the edge of one set's spread meets the view at the edge of the other's.
Eigen::Vector2f RelativeViewOffset(const Eigen::Vector3f& local_direction, float spread);

class DescriptorBank {
 public:
  DescriptorBank() = default;
  // Tracks of views: track t holds views [track_offsets[t], track_offsets[t + 1]); every row of
  // the matrices is a view. Night rows are zero where `has_night` is 0. Throws
  // std::invalid_argument when the parts do not fit together (Check).
  DescriptorBank(std::string feature, std::vector<std::string> sources,
                 std::vector<uint32_t> track_offsets, DescriptorMatrix day,
                 ViewDirectionMatrix directions, DescriptorMatrix night,
                 std::vector<uint8_t> has_night);

  const std::string& feature() const { return feature_; }
  // The sets the bank was made from, as given to `hscloc bank`.
  const std::vector<std::string>& sources() const { return sources_; }
  int64_t dimension() const { return day_.cols(); }
  size_t NumTracks() const { return track_offsets_.empty() ? 0 : track_offsets_.size() - 1; }
  size_t NumViews() const { return static_cast<size_t>(day_.rows()); }
  size_t NumNightViews() const;
  uint32_t FirstView(size_t track) const { return track_offsets_.at(track); }
  uint32_t EndView(size_t track) const { return track_offsets_.at(track + 1); }

  // Unit descriptors, one row per view.
  const DescriptorMatrix& day() const { return day_; }
  const DescriptorMatrix& night() const { return night_; }
  bool HasNight(uint32_t view) const { return has_night_.at(view) != 0; }
  // Unit local view directions (LocalViewDirection), one row per view.
  const ViewDirectionMatrix& directions() const { return directions_; }

  // The view of `track` whose relative offset (RelativeViewOffset by the track's own spread) is
  // nearest `relative_offset`; the first of equals.
  uint32_t NearestView(size_t track, const Eigen::Vector2f& relative_offset) const;
  // The spread of a track's view directions (DirectionSpread).
  float TrackSpread(size_t track) const;

  // Several banks as one (their tracks one after the other); all of one feature and dimension.
  static DescriptorBank Concatenate(const std::vector<DescriptorBank>& banks);

  // A binary file (magic, version, feature, sources, then the arrays); Save writes a temporary
  // file and renames it, so a reader never sees half a bank.
  void Save(const std::filesystem::path& path) const;
  // Throws std::invalid_argument naming the file when it is missing, not a bank, of another
  // version, truncated or inconsistent.
  static DescriptorBank Load(const std::filesystem::path& path);

  // Throws std::invalid_argument naming the first inconsistency.
  void Check() const;
  bool operator==(const DescriptorBank& other) const;

 private:
  std::string feature_;
  std::vector<std::string> sources_;
  std::vector<uint32_t> track_offsets_;
  DescriptorMatrix day_;
  ViewDirectionMatrix directions_;
  DescriptorMatrix night_;
  std::vector<uint8_t> has_night_;
};

}  // namespace hscloc
