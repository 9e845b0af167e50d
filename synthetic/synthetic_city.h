// A synthetic, Aachen-like city with known ground truth: a street grid of building blocks whose
// facades (and some ground) carry 3D points, database cameras along the streets, held-out day and
// night queries, and SuperPoint-like descriptors with repeated structure (windows that look the
// same on different buildings), so that a descriptor alone is ambiguous and only context tells
// the points apart.
//
// World frame: metres, z up, ground at z = 0. Cameras follow COLMAP (x right, y down, z forward).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "geometry/camera.h"
#include "geometry/rigid3d.h"
#include "scene/descriptor_bank.h"
#include "scene/features.h"

namespace hscloc {

struct SyntheticCityOptions {
  uint64_t seed = 0;

  // --- Geometry: a grid of blocks_x x blocks_y rectangular buildings separated by streets.
  int blocks_x = 3;
  int blocks_y = 3;
  double block_size_m = 36.0;  // side of a block's footprint
  double street_width_m = 14.0;
  double building_height_min_m = 10.0;
  double building_height_max_m = 22.0;
  double facade_points_per_m2 = 1.5;
  double ground_points_per_m2 = 0.03;  // on the streets

  // --- Database cameras: stops along the street centre lines, several headings per stop.
  double stop_spacing_m = 6.0;
  int headings_per_stop = 2;  // 2: both sides; 4: also the diagonals ahead
  double heading_jitter_deg = 15.0;
  double eye_height_m = 1.6;
  double pitch_up_max_deg = 12.0;
  double lateral_jitter_m = 2.0;  // off the street centre line
  double focal_min_px = 700.0;    // each device draws its focal length in [min, max]
  double focal_max_px = 1200.0;
  int num_devices = 3;  // distinct intrinsics (COLMAP cameras) of the database
  int image_width_px = 1024;
  int image_height_px = 768;
  double radial_distortion_max = 0.05;  // |k| of SIMPLE_RADIAL

  // --- Visibility.
  double max_range_m = 60.0;
  double min_viewing_cos = 0.15;  // cos of the angle between facade normal and viewing ray
  double image_margin_px = 2.0;
  double keypoint_noise_px = 0.5;  // standard deviation per axis
  int max_keypoints_per_image = 2048;
  int min_track_length = 2;  // database observations a point needs to enter the map

  // --- Appearance.
  int descriptor_dim = 256;
  double repeated_fraction = 0.2;  // points that copy the descriptor of a point on another building
  double day_descriptor_noise = 0.35;  // norm of the noise added to a unit descriptor
  int clutter_per_image = 150;         // detections of no 3D point
  // With a descriptor bank (real appearance): the norm of the noise that tells a track's second
  // and later uses apart, fixed per point that uses it; 0 (copies alike, up to each view's noise)
  // keeps the confusion between points nearest the real sets' (docs/decisions.md).
  double bank_reuse_noise = 0.0;
  // With a descriptor bank: the norm of the noise each view adds to its bank view's descriptor.
  // A synthetic point may have more views than its track, and views that take the same bank view
  // would otherwise be identical; 0.2 brings the best cosine of a view with another view of its
  // point to the real sets' (docs/decisions.md, "Real appearance").
  double bank_view_noise = 0.2;

  // --- Queries (held out: not database images).
  int num_day_queries = 50;
  int num_night_queries = 50;
  double query_yaw_jitter_deg = 30.0;
  double query_roll_max_deg = 5.0;
  double query_focal_min_px = 600.0;
  double query_focal_max_px = 1400.0;
  int min_query_points = 60;  // visible map points a query view must have
  double night_descriptor_noise = 0.8;
  double night_detection_rate = 0.6;  // share of visible points detected at night
  int night_clutter_per_image = 400;

  // Throws std::invalid_argument naming the first field out of range.
  void Check() const;

  // "tiny" (a unit test in < 2 s), "small" (hundreds of images), "city" (a few thousand images),
  // "aachen" (about 4,300 database images and 1.5 M points, like Aachen Day-Night).
  static SyntheticCityOptions Preset(const std::string& name);
  static std::vector<std::string> PresetNames();
};

enum class QueryCondition { kDay, kNight };
std::string QueryConditionName(QueryCondition condition);

// A posed image of the city: database image or query.
struct SyntheticView {
  std::string name;  // "db/00012.jpg", "query/day/00003.jpg", "query/night/00003.jpg"
  Camera camera;
  Rigid3d cam_from_world;
};

// The features of one view and, per keypoint, the city point it detects (-1: clutter).
struct SyntheticViewFeatures {
  ImageFeatures features;
  std::vector<int64_t> point_of_keypoint;
};

// The city's geometry, cameras and appearance model. Features are generated on demand from
// counter-based random streams, so any view's features can be made in any order, on any thread,
// with the same result.
class Random;

class SyntheticCity {
 public:
  // Lays out the city (blocks, points, database views, queries); Check()s the options. With a
  // descriptor bank the appearance is real: each point takes a track of the bank (tracks repeat
  // when the city has more points, every track as often), each view the descriptor of the
  // track's view nearest in viewing direction (relative to the spread of the point's views and
  // of the track's: RelativeViewOffset), night views its night descriptor (a point whose
  // view was not found again at night is not detected), and clutter other tracks' descriptors;
  // descriptor_dim becomes the bank's. Throws std::invalid_argument for a bank without tracks.
  explicit SyntheticCity(const SyntheticCityOptions& options,
                         std::shared_ptr<const DescriptorBank> bank = nullptr);

  const SyntheticCityOptions& options() const { return options_; }
  const std::vector<Eigen::AlignedBox3d>& blocks() const { return blocks_; }
  const std::vector<Eigen::Vector3d>& points() const { return points_; }
  // Outward surface normal of each point's facade (or +z on the ground).
  const std::vector<Eigen::Vector3d>& point_normals() const { return point_normals_; }
  // Block of each point, -1 for ground points.
  const std::vector<int>& point_blocks() const { return point_blocks_; }
  // The point whose appearance each point shares: itself, or for a repeated point, the point on
  // another building it copies.
  const std::vector<uint32_t>& appearance_of_point() const { return appearance_of_point_; }
  const std::vector<Camera>& database_cameras() const { return database_cameras_; }
  const std::vector<SyntheticView>& database_views() const { return database_views_; }
  const std::vector<SyntheticView>& queries(QueryCondition condition) const {
    return condition == QueryCondition::kDay ? day_queries_ : night_queries_;
  }

  // Indices of the points a view sees: in front, inside the image, within range, on a facade
  // facing the camera and not hidden behind a block. Sorted.
  std::vector<uint32_t> VisiblePoints(const Camera& camera, const Rigid3d& cam_from_world) const;
  // True when the segment from `from` to `to` crosses no block.
  bool IsSegmentFree(const Eigen::Vector3d& from, const Eigen::Vector3d& to) const;

  // The noise-free unit descriptor of a point (shared by repeated points); with a bank, its
  // track's view nearest its mean viewing direction.
  Eigen::VectorXf PointDescriptor(uint32_t point_index) const;
  // The bank, or nullptr for the random appearance.
  const DescriptorBank* bank() const { return bank_.get(); }
  // With a bank: the track a point's appearance takes.
  uint32_t TrackOfPoint(uint32_t point_index) const;
  // With a bank: the bank view whose descriptor a view from `camera_center` gets of the point.
  uint32_t BankViewOfPoint(uint32_t point_index, const Eigen::Vector3d& camera_center) const;

  // Keypoints (projections plus pixel noise, in random order, capped at max_keypoints_per_image)
  // and descriptors (point descriptor plus noise, renormalized) of a view; `view_key` addresses the
  // random stream (distinct per view). Night views detect fewer points, add more clutter, and have
  // stronger descriptor noise.
  SyntheticViewFeatures MakeViewFeatures(const SyntheticView& view, QueryCondition condition,
                                         uint64_t view_key) const;

 private:
  void LayOutBlocksAndPoints();
  void AssignRepeatedAppearance();
  void PlaceDatabaseViews();
  void PlaceQueries(QueryCondition condition);
  // Blocks whose footprint lies within `range` of (x, y).
  std::vector<int> BlocksNear(double x, double y, double range) const;
  // With a bank: checks it and deals its tracks out in a seeded order (track_order_).
  void DealBankTracks();
  // Fills viewing_references_ (a pass over the database views' visible points).
  void ComputeViewingReferences();
  // The points a view detects, at most max_points of them, in random order.
  std::vector<uint32_t> DetectedPoints(const SyntheticView& view, bool night, size_t max_points,
                                       Random& random) const;
  // The unit descriptor a view from `camera_center` sees of point p, with `random` for the
  // random appearance's noise.
  Eigen::VectorXf ObservedDescriptor(uint32_t p, const Eigen::Vector3d& camera_center, bool night,
                                     Random& random) const;
  // The bank view's descriptor for point p (the night one at night), offset for a reused track.
  Eigen::VectorXf ObservedDescriptorFromBank(uint32_t point_index, uint32_t view, bool night) const;
  // A detection of no point: a random unit vector, or with a bank a random view's descriptor.
  Eigen::VectorXf ClutterDescriptor(bool night, Random& random) const;

  SyntheticCityOptions options_;
  std::shared_ptr<const DescriptorBank> bank_;
  // With a bank: tracks in a seeded random order; appearance a takes track_order_[a % tracks].
  std::vector<uint32_t> track_order_;
  // With a bank: each point's mean viewing direction from the database views that see it (its
  // facade normal when none does), the reference its views' directions are taken against, as a
  // bank track's are against its mean.
  std::vector<Eigen::Vector3d> viewing_references_;
  std::vector<float> viewing_spreads_;  // DirectionSpread of those views
  std::vector<Eigen::AlignedBox3d> blocks_;
  std::vector<Eigen::Vector3d> points_;
  std::vector<Eigen::Vector3d> point_normals_;
  std::vector<int> point_blocks_;
  std::vector<uint32_t> appearance_of_point_;
  std::vector<std::vector<uint32_t>> points_of_block_;
  std::vector<uint32_t> ground_points_;
  std::vector<Camera> database_cameras_;
  std::vector<SyntheticView> database_views_;
  std::vector<SyntheticView> day_queries_;
  std::vector<SyntheticView> night_queries_;
};

}  // namespace hscloc
