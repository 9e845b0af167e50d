#include "synthetic/synthetic_city.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>

#include "synthetic/random_streams.h"
#include "util/check.h"
#include "util/random.h"

namespace hscloc {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

// Points are lifted off their surface by this much before the occlusion test so that the facade
// a point lies on does not hide it.
constexpr double kSurfaceOffsetM = 0.05;

// world_from_cam rotation of a camera at eye level looking along `yaw` (radians, from +x towards
// +y), tilted up by `pitch` and rolled by `roll` about its viewing direction.
Eigen::Matrix3d WorldFromCamRotation(double yaw, double pitch, double roll) {
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d forward(std::cos(yaw) * std::cos(pitch), std::sin(yaw) * std::cos(pitch),
                                std::sin(pitch));
  const Eigen::Vector3d right = forward.cross(up).normalized();
  const Eigen::Vector3d down = forward.cross(right);
  Eigen::Matrix3d world_from_cam;
  world_from_cam << right, down, forward;
  return world_from_cam * Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

Camera MakeSimpleRadialCamera(camera_t camera_id, int width, int height, double focal_px,
                              Random& random, double radial_distortion_max) {
  Camera camera;
  camera.camera_id = camera_id;
  camera.model_id = CameraModelId::kSimpleRadial;
  camera.width = width;
  camera.height = height;
  camera.params = {focal_px, width / 2.0 + random.Uniform(-0.01, 0.01) * width,
                   height / 2.0 + random.Uniform(-0.01, 0.01) * height,
                   random.Uniform(-radial_distortion_max, radial_distortion_max)};
  return camera;
}

Eigen::VectorXf RandomUnitVector(Random& random, int dimension) {
  Eigen::VectorXf vector(dimension);
  for (int i = 0; i < dimension; ++i) vector[i] = static_cast<float>(random.Normal());
  return vector.normalized();
}

}  // namespace

void SyntheticCityOptions::Check() const {
  THROW_CHECK_MSG(blocks_x >= 1 && blocks_y >= 1, "blocks_x and blocks_y must be >= 1 (got {}, {})",
                  blocks_x, blocks_y);
  THROW_CHECK_MSG(block_size_m > 0, "block_size_m must be positive (got {})", block_size_m);
  THROW_CHECK_MSG(street_width_m >= 4, "street_width_m must be >= 4 (got {})", street_width_m);
  THROW_CHECK_MSG(
      building_height_min_m > eye_height_m && building_height_max_m >= building_height_min_m,
      "building heights must satisfy eye_height_m < building_height_min_m <= "
      "building_height_max_m (got {}, {})",
      building_height_min_m, building_height_max_m);
  THROW_CHECK_MSG(facade_points_per_m2 > 0, "facade_points_per_m2 must be positive (got {})",
                  facade_points_per_m2);
  THROW_CHECK_MSG(ground_points_per_m2 >= 0, "ground_points_per_m2 must be >= 0 (got {})",
                  ground_points_per_m2);
  THROW_CHECK_MSG(stop_spacing_m > 0, "stop_spacing_m must be positive (got {})", stop_spacing_m);
  THROW_CHECK_MSG(headings_per_stop >= 1 && headings_per_stop <= 4,
                  "headings_per_stop must be in [1, 4] (got {})", headings_per_stop);
  THROW_CHECK_MSG(eye_height_m > 0, "eye_height_m must be positive (got {})", eye_height_m);
  THROW_CHECK_MSG(lateral_jitter_m >= 0 && lateral_jitter_m < street_width_m / 2 - 1,
                  "lateral_jitter_m must be in [0, street_width_m / 2 - 1) (got {})",
                  lateral_jitter_m);
  THROW_CHECK_MSG(focal_min_px > 0 && focal_max_px >= focal_min_px,
                  "focal_min_px must be positive and <= focal_max_px (got {}, {})", focal_min_px,
                  focal_max_px);
  THROW_CHECK_MSG(query_focal_min_px > 0 && query_focal_max_px >= query_focal_min_px,
                  "query_focal_min_px must be positive and <= query_focal_max_px (got {}, {})",
                  query_focal_min_px, query_focal_max_px);
  THROW_CHECK_MSG(num_devices >= 1, "num_devices must be >= 1 (got {})", num_devices);
  THROW_CHECK_MSG(image_width_px >= 64 && image_height_px >= 64,
                  "image_width_px and image_height_px must be >= 64 (got {}, {})", image_width_px,
                  image_height_px);
  THROW_CHECK_MSG(radial_distortion_max >= 0 && radial_distortion_max <= 0.2,
                  "radial_distortion_max must be in [0, 0.2] (got {})", radial_distortion_max);
  THROW_CHECK_MSG(max_range_m > 0, "max_range_m must be positive (got {})", max_range_m);
  THROW_CHECK_MSG(min_viewing_cos >= 0 && min_viewing_cos < 1,
                  "min_viewing_cos must be in [0, 1) (got {})", min_viewing_cos);
  THROW_CHECK_MSG(keypoint_noise_px >= 0, "keypoint_noise_px must be >= 0 (got {})",
                  keypoint_noise_px);
  THROW_CHECK_MSG(max_keypoints_per_image >= 16, "max_keypoints_per_image must be >= 16 (got {})",
                  max_keypoints_per_image);
  THROW_CHECK_MSG(min_track_length >= 1, "min_track_length must be >= 1 (got {})",
                  min_track_length);
  THROW_CHECK_MSG(descriptor_dim >= 2 && descriptor_dim <= 4096,
                  "descriptor_dim must be in [2, 4096] (got {})", descriptor_dim);
  THROW_CHECK_MSG(repeated_fraction >= 0 && repeated_fraction <= 0.9,
                  "repeated_fraction must be in [0, 0.9] (got {})", repeated_fraction);
  THROW_CHECK_MSG(day_descriptor_noise >= 0 && night_descriptor_noise >= 0,
                  "day_descriptor_noise and night_descriptor_noise must be >= 0 (got {}, {})",
                  day_descriptor_noise, night_descriptor_noise);
  THROW_CHECK_MSG(clutter_per_image >= 0 && night_clutter_per_image >= 0,
                  "clutter_per_image and night_clutter_per_image must be >= 0 (got {}, {})",
                  clutter_per_image, night_clutter_per_image);
  THROW_CHECK_MSG(num_day_queries >= 0 && num_night_queries >= 0,
                  "num_day_queries and num_night_queries must be >= 0 (got {}, {})",
                  num_day_queries, num_night_queries);
  THROW_CHECK_MSG(night_detection_rate > 0 && night_detection_rate <= 1,
                  "night_detection_rate must be in (0, 1] (got {})", night_detection_rate);
  THROW_CHECK_MSG(min_query_points >= 0, "min_query_points must be >= 0 (got {})",
                  min_query_points);
  THROW_CHECK_MSG(blocks_x * blocks_y >= 2 || repeated_fraction == 0,
                  "repeated_fraction > 0 needs at least two blocks to copy between (got {} x {})",
                  blocks_x, blocks_y);
}

SyntheticCityOptions SyntheticCityOptions::Preset(const std::string& name) {
  SyntheticCityOptions options;
  if (name == "tiny") {
    options.blocks_x = 2;
    options.blocks_y = 2;
    options.block_size_m = 24;
    options.building_height_max_m = 14;
    options.facade_points_per_m2 = 0.25;
    options.stop_spacing_m = 8;
    options.descriptor_dim = 64;
    options.clutter_per_image = 40;
    options.night_clutter_per_image = 100;
    options.num_day_queries = 6;
    options.num_night_queries = 6;
    options.min_query_points = 40;
  } else if (name == "small") {
    // Defaults: 3 x 3 blocks, a few hundred images.
  } else if (name == "city") {
    options.blocks_x = 6;
    options.blocks_y = 6;
    options.facade_points_per_m2 = 2.0;
    options.stop_spacing_m = 4;
    options.num_day_queries = 200;
    options.num_night_queries = 100;
  } else if (name == "aachen") {
    options.blocks_x = 10;
    options.blocks_y = 10;
    options.block_size_m = 40;
    options.facade_points_per_m2 = 8.2;
    options.stop_spacing_m = 5.5;
    options.num_devices = 8;
    options.max_keypoints_per_image = 4096;
    options.num_day_queries = 824;
    options.num_night_queries = 98;
  } else {
    ThrowInvalidArgument("unknown synthetic city preset '{}' (tiny, small, city, aachen)", name);
  }
  return options;
}

std::vector<std::string> SyntheticCityOptions::PresetNames() {
  return {"tiny", "small", "city", "aachen"};
}

std::string QueryConditionName(QueryCondition condition) {
  return condition == QueryCondition::kDay ? "day" : "night";
}

SyntheticCity::SyntheticCity(const SyntheticCityOptions& options,
                             std::shared_ptr<const DescriptorBank> bank)
    : options_(options), bank_(std::move(bank)) {
  if (bank_ != nullptr) DealBankTracks();
  THROW_CHECK_MSG(options_.bank_reuse_noise >= 0 && options_.bank_view_noise >= 0,
                  "bank_reuse_noise and bank_view_noise must be >= 0 (got {}, {})",
                  options_.bank_reuse_noise, options_.bank_view_noise);
  options_.Check();
  LayOutBlocksAndPoints();
  AssignRepeatedAppearance();
  PlaceDatabaseViews();
  if (bank_ != nullptr) ComputeViewingReferences();
  PlaceQueries(QueryCondition::kDay);
  PlaceQueries(QueryCondition::kNight);
}

void SyntheticCity::LayOutBlocksAndPoints() {
  const double pitch = options_.block_size_m + options_.street_width_m;
  Random heights(options_.seed, {kStreamHeights});
  for (int j = 0; j < options_.blocks_y; ++j) {
    for (int i = 0; i < options_.blocks_x; ++i) {
      const double x0 = options_.street_width_m + i * pitch;
      const double y0 = options_.street_width_m + j * pitch;
      const double height =
          heights.Uniform(options_.building_height_min_m, options_.building_height_max_m);
      blocks_.emplace_back(
          Eigen::Vector3d(x0, y0, 0),
          Eigen::Vector3d(x0 + options_.block_size_m, y0 + options_.block_size_m, height));
    }
  }

  points_of_block_.resize(blocks_.size());
  for (size_t b = 0; b < blocks_.size(); ++b) {
    Random random(options_.seed, {kStreamFacadePoints, b});
    const Eigen::AlignedBox3d& box = blocks_[b];
    const double height = box.max().z();
    // Four facades: (origin, direction along the facade, outward normal).
    const Eigen::Vector3d lo = box.min();
    const Eigen::Vector3d hi = box.max();
    const double side = options_.block_size_m;
    const std::array<std::array<Eigen::Vector3d, 3>, 4> facades = {{
        {Eigen::Vector3d(lo.x(), lo.y(), 0), Eigen::Vector3d::UnitX(), -Eigen::Vector3d::UnitY()},
        {Eigen::Vector3d(lo.x(), hi.y(), 0), Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY()},
        {Eigen::Vector3d(lo.x(), lo.y(), 0), Eigen::Vector3d::UnitY(), -Eigen::Vector3d::UnitX()},
        {Eigen::Vector3d(hi.x(), lo.y(), 0), Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitX()},
    }};
    const int points_per_facade =
        static_cast<int>(std::lround(side * height * options_.facade_points_per_m2));
    for (const auto& [origin, along, normal] : facades) {
      for (int k = 0; k < points_per_facade; ++k) {
        points_of_block_[b].push_back(static_cast<uint32_t>(points_.size()));
        points_.push_back(origin + random.Uniform(0, side) * along +
                          random.Uniform(0.3, height) * Eigen::Vector3d::UnitZ());
        point_normals_.push_back(normal);
        point_blocks_.push_back(static_cast<int>(b));
      }
    }
  }

  // Ground points on the streets: sample the whole extent and drop those under buildings.
  const double extent_x = options_.blocks_x * pitch + options_.street_width_m;
  const double extent_y = options_.blocks_y * pitch + options_.street_width_m;
  const double street_area =
      extent_x * extent_y - blocks_.size() * options_.block_size_m * options_.block_size_m;
  const int num_ground = static_cast<int>(std::lround(street_area * options_.ground_points_per_m2));
  Random random(options_.seed, {kStreamGroundPoints});
  while (static_cast<int>(ground_points_.size()) < num_ground) {
    const Eigen::Vector3d point(random.Uniform(0, extent_x), random.Uniform(0, extent_y), 0);
    const bool under_building = std::any_of(blocks_.begin(), blocks_.end(), [&](const auto& box) {
      return point.x() > box.min().x() && point.x() < box.max().x() && point.y() > box.min().y() &&
             point.y() < box.max().y();
    });
    if (under_building) continue;
    ground_points_.push_back(static_cast<uint32_t>(points_.size()));
    points_.push_back(point);
    point_normals_.push_back(Eigen::Vector3d::UnitZ());
    point_blocks_.push_back(-1);
  }
}

void SyntheticCity::AssignRepeatedAppearance() {
  const size_t num_points = points_.size();
  appearance_of_point_.resize(num_points);
  std::iota(appearance_of_point_.begin(), appearance_of_point_.end(), 0u);
  if (options_.repeated_fraction == 0) return;

  Random random(options_.seed, {kStreamRepeated});
  std::vector<char> repeated(num_points, 0);
  for (size_t p = 0; p < num_points; ++p)
    repeated[p] = random.Bernoulli(options_.repeated_fraction);
  std::vector<uint32_t> originals;
  for (size_t p = 0; p < num_points; ++p) {
    if (!repeated[p] && point_blocks_[p] >= 0) originals.push_back(static_cast<uint32_t>(p));
  }
  THROW_CHECK_MSG(!originals.empty(), "repeated_fraction {} leaves no facade point to copy",
                  options_.repeated_fraction);
  for (size_t p = 0; p < num_points; ++p) {
    if (!repeated[p]) continue;
    // A repeated point copies a point on another building; a handful of draws always finds one
    // because blocks hold equal shares of the points.
    for (int attempt = 0; attempt < 64; ++attempt) {
      const uint32_t source = originals[random.UniformInt(originals.size())];
      if (point_blocks_[source] != point_blocks_[p]) {
        appearance_of_point_[p] = source;
        break;
      }
    }
  }
}

void SyntheticCity::PlaceDatabaseViews() {
  Random devices(options_.seed, {kStreamDevices});
  for (int d = 0; d < options_.num_devices; ++d) {
    database_cameras_.push_back(MakeSimpleRadialCamera(
        static_cast<camera_t>(d + 1), options_.image_width_px, options_.image_height_px,
        devices.Uniform(options_.focal_min_px, options_.focal_max_px), devices,
        options_.radial_distortion_max));
  }

  const double pitch = options_.block_size_m + options_.street_width_m;
  const double half_street = options_.street_width_m / 2;
  // Street centre lines: along x at each row gap, along y at each column gap.
  struct Street {
    Eigen::Vector2d start, direction;
    double length;
  };
  std::vector<Street> streets;
  const double extent_x = options_.blocks_x * pitch + options_.street_width_m;
  const double extent_y = options_.blocks_y * pitch + options_.street_width_m;
  for (int j = 0; j <= options_.blocks_y; ++j) {
    streets.push_back({{half_street, half_street + j * pitch}, {1, 0}, extent_x - 2 * half_street});
  }
  for (int i = 0; i <= options_.blocks_x; ++i) {
    streets.push_back({{half_street + i * pitch, half_street}, {0, 1}, extent_y - 2 * half_street});
  }

  const double heading_offsets[4] = {M_PI / 2, -M_PI / 2, M_PI / 4, -M_PI / 4};
  Random random(options_.seed, {kStreamDatabaseViews});
  for (const Street& street : streets) {
    const Eigen::Vector2d left(-street.direction.y(), street.direction.x());
    const double street_yaw = std::atan2(street.direction.y(), street.direction.x());
    const int num_stops = static_cast<int>(street.length / options_.stop_spacing_m) + 1;
    for (int s = 0; s < num_stops; ++s) {
      const Eigen::Vector2d ground = street.start + s * options_.stop_spacing_m * street.direction +
                                     random.Uniform(-1, 1) * options_.lateral_jitter_m * left;
      const Eigen::Vector3d center(ground.x(), ground.y(),
                                   options_.eye_height_m + random.Uniform(-0.1, 0.1));
      for (int h = 0; h < options_.headings_per_stop; ++h) {
        const double yaw = street_yaw + heading_offsets[h] +
                           random.Uniform(-1, 1) * options_.heading_jitter_deg * kDegToRad;
        const double pitch_up = random.Uniform(0, options_.pitch_up_max_deg) * kDegToRad;
        SyntheticView view;
        view.name = fmt::format("db/{:05d}.jpg", database_views_.size());
        view.camera = database_cameras_[random.UniformInt(database_cameras_.size())];
        view.cam_from_world =
            CamFromWorldFromCenter(center, WorldFromCamRotation(yaw, pitch_up, 0.0));
        database_views_.push_back(std::move(view));
      }
    }
  }
}

void SyntheticCity::PlaceQueries(QueryCondition condition) {
  const int count =
      condition == QueryCondition::kDay ? options_.num_day_queries : options_.num_night_queries;
  std::vector<SyntheticView>& queries =
      condition == QueryCondition::kDay ? day_queries_ : night_queries_;
  const double pitch = options_.block_size_m + options_.street_width_m;
  const double half_street = options_.street_width_m / 2;
  const int sizes[3][2] = {{1024, 768}, {1280, 960}, {800, 600}};
  Random random(options_.seed, {kStreamQueries, static_cast<uint64_t>(condition)});
  constexpr int kMaxAttemptsPerQuery = 200;
  for (int q = 0; q < count; ++q) {
    for (int attempt = 0;; ++attempt) {
      THROW_CHECK_MSG(attempt < kMaxAttemptsPerQuery,
                      "no {} query view sees min_query_points = {} points after {} attempts",
                      QueryConditionName(condition), options_.min_query_points, attempt);
      // A random point on a random street, anywhere across its width.
      const bool along_x = random.Bernoulli(0.5);
      const int lines = along_x ? options_.blocks_y + 1 : options_.blocks_x + 1;
      const double length =
          (along_x ? options_.blocks_x : options_.blocks_y) * pitch + options_.street_width_m;
      const double across = half_street + random.UniformInt(lines) * pitch +
                            random.Uniform(-1, 1) * (half_street - 1.5);
      const double along = random.Uniform(half_street, length - half_street);
      const Eigen::Vector3d center(along_x ? along : across, along_x ? across : along,
                                   options_.eye_height_m + random.Uniform(-0.3, 0.3));
      const double street_yaw = along_x ? 0.0 : M_PI / 2;
      const double side = random.Bernoulli(0.5) ? M_PI / 2 : -M_PI / 2;
      const double yaw =
          street_yaw + side + random.Uniform(-1, 1) * options_.query_yaw_jitter_deg * kDegToRad;
      const double pitch_up = random.Uniform(0, options_.pitch_up_max_deg) * kDegToRad;
      const double roll = random.Uniform(-1, 1) * options_.query_roll_max_deg * kDegToRad;
      const auto& size = sizes[random.UniformInt(3)];
      SyntheticView view;
      // Unique basenames, as in Aachen: submissions name queries by basename.
      view.name = fmt::format("query/{0}/{0}_{1:05d}.jpg", QueryConditionName(condition), q);
      view.camera = MakeSimpleRadialCamera(
          static_cast<camera_t>(q + 1), size[0], size[1],
          random.Uniform(options_.query_focal_min_px, options_.query_focal_max_px), random,
          options_.radial_distortion_max);
      view.cam_from_world =
          CamFromWorldFromCenter(center, WorldFromCamRotation(yaw, pitch_up, roll));
      if (static_cast<int>(VisiblePoints(view.camera, view.cam_from_world).size()) >=
          options_.min_query_points) {
        queries.push_back(std::move(view));
        break;
      }
    }
  }
}

std::vector<int> SyntheticCity::BlocksNear(double x, double y, double range) const {
  std::vector<int> near;
  for (size_t b = 0; b < blocks_.size(); ++b) {
    const Eigen::AlignedBox3d& box = blocks_[b];
    const double dx = std::max({box.min().x() - x, 0.0, x - box.max().x()});
    const double dy = std::max({box.min().y() - y, 0.0, y - box.max().y()});
    if (dx * dx + dy * dy <= range * range) near.push_back(static_cast<int>(b));
  }
  return near;
}

bool SyntheticCity::IsSegmentFree(const Eigen::Vector3d& from, const Eigen::Vector3d& to) const {
  const Eigen::Vector3d delta = to - from;
  const double pitch = options_.block_size_m + options_.street_width_m;
  // Only blocks whose grid column and row overlap the segment's footprint can be hit.
  auto index_range = [&](double a, double b, int count) {
    const double low = std::min(a, b) - options_.street_width_m - options_.block_size_m;
    const double high = std::max(a, b) - options_.street_width_m;
    return std::make_pair(std::max(0, static_cast<int>(std::ceil(low / pitch))),
                          std::min(count - 1, static_cast<int>(std::floor(high / pitch))));
  };
  const auto [i_low, i_high] = index_range(from.x(), to.x(), options_.blocks_x);
  const auto [j_low, j_high] = index_range(from.y(), to.y(), options_.blocks_y);
  for (int j = j_low; j <= j_high; ++j) {
    for (int i = i_low; i <= i_high; ++i) {
      const Eigen::AlignedBox3d& box = blocks_[j * options_.blocks_x + i];
      // Slab test of the segment against the box.
      double t_enter = 0, t_exit = 1;
      bool missed = false;
      for (int axis = 0; axis < 3 && !missed; ++axis) {
        if (std::abs(delta[axis]) < 1e-12) {
          missed = from[axis] < box.min()[axis] || from[axis] > box.max()[axis];
          continue;
        }
        double t0 = (box.min()[axis] - from[axis]) / delta[axis];
        double t1 = (box.max()[axis] - from[axis]) / delta[axis];
        if (t0 > t1) std::swap(t0, t1);
        t_enter = std::max(t_enter, t0);
        t_exit = std::min(t_exit, t1);
        missed = t_enter > t_exit;
      }
      if (!missed) return false;
    }
  }
  return true;
}

std::vector<uint32_t> SyntheticCity::VisiblePoints(const Camera& camera,
                                                   const Rigid3d& cam_from_world) const {
  const Eigen::Vector3d center = CameraCenterInWorld(cam_from_world);
  const double focal = camera.MeanFocalLength();
  // Distortion models fold far off-axis rays back into the image: first require the undistorted
  // projection to be near the image.
  const double max_normalized_x = 0.6 * camera.width / focal;
  const double max_normalized_y = 0.6 * camera.height / focal;
  const double margin = options_.image_margin_px;
  std::vector<uint32_t> visible;
  auto consider = [&](uint32_t p) {
    const Eigen::Vector3d& point = points_[p];
    const Eigen::Vector3d to_camera = center - point;
    const double distance = to_camera.norm();
    if (distance > options_.max_range_m) return;
    if (point_normals_[p].dot(to_camera) < options_.min_viewing_cos * distance) return;
    const Eigen::Vector3d point_in_cam = cam_from_world * point;
    if (point_in_cam.z() < 0.1) return;
    const Eigen::Vector2d normalized = point_in_cam.hnormalized();
    if (std::abs(normalized.x()) > max_normalized_x ||
        std::abs(normalized.y()) > max_normalized_y) {
      return;
    }
    const Eigen::Vector2d pixel = camera.ImgFromCam(normalized);
    if (pixel.x() < margin || pixel.y() < margin || pixel.x() > camera.width - margin ||
        pixel.y() > camera.height - margin) {
      return;
    }
    if (!IsSegmentFree(center, point + kSurfaceOffsetM * point_normals_[p])) return;
    visible.push_back(p);
  };
  for (const int block : BlocksNear(center.x(), center.y(), options_.max_range_m)) {
    for (const uint32_t p : points_of_block_[block]) consider(p);
  }
  for (const uint32_t p : ground_points_) consider(p);
  std::sort(visible.begin(), visible.end());
  return visible;
}

Eigen::VectorXf SyntheticCity::PointDescriptor(uint32_t point_index) const {
  if (bank_ != nullptr) {
    return ObservedDescriptorFromBank(
        point_index, bank_->NearestView(TrackOfPoint(point_index), Eigen::Vector2f::Zero()), false);
  }
  Random random(options_.seed, {kStreamPointDescriptor, appearance_of_point_[point_index]});
  return RandomUnitVector(random, options_.descriptor_dim);
}

std::vector<uint32_t> SyntheticCity::DetectedPoints(const SyntheticView& view, bool night,
                                                    size_t max_points, Random& random) const {
  const Eigen::Vector3d center = CameraCenterInWorld(view.cam_from_world);
  std::vector<uint32_t> detected;
  for (const uint32_t p : VisiblePoints(view.camera, view.cam_from_world)) {
    // At night a real view is detected where its keypoint was found again in the night photo.
    const bool seen =
        !night || (bank_ != nullptr ? bank_->HasNight(BankViewOfPoint(p, center))
                                    : random.Bernoulli(options_.night_detection_rate));
    if (seen) detected.push_back(p);
  }
  if (detected.size() > max_points) {
    // A partial Fisher-Yates shuffle keeps a uniform random subset.
    for (size_t i = 0; i < max_points; ++i) {
      std::swap(detected[i], detected[i + random.UniformInt(detected.size() - i)]);
    }
    detected.resize(max_points);
  }
  return detected;
}

Eigen::VectorXf SyntheticCity::ObservedDescriptor(uint32_t p, const Eigen::Vector3d& camera_center,
                                                  bool night, Random& random) const {
  if (bank_ != nullptr) {
    Eigen::VectorXf descriptor =
        ObservedDescriptorFromBank(p, BankViewOfPoint(p, camera_center), night);
    if (options_.bank_view_noise > 0) {
      const double per_dimension =
          options_.bank_view_noise / std::sqrt(static_cast<double>(descriptor.size()));
      for (int64_t d = 0; d < descriptor.size(); ++d) {
        descriptor[d] += per_dimension * random.Normal();
      }
      descriptor.normalize();
    }
    return descriptor;
  }
  const int dim = options_.descriptor_dim;
  const double noise = night ? options_.night_descriptor_noise : options_.day_descriptor_noise;
  const double noise_per_dimension = noise / std::sqrt(static_cast<double>(dim));
  Eigen::VectorXf descriptor = PointDescriptor(p);
  for (int d = 0; d < dim; ++d) descriptor[d] += noise_per_dimension * random.Normal();
  descriptor.normalize();
  return descriptor;
}

Eigen::VectorXf SyntheticCity::ClutterDescriptor(bool night, Random& random) const {
  if (bank_ == nullptr) return RandomUnitVector(random, options_.descriptor_dim);
  // Another view of the bank, found again at night for a night view (a few draws; the day
  // descriptor when none was).
  uint32_t view = static_cast<uint32_t>(random.UniformInt(bank_->NumViews()));
  for (int attempt = 0; night && !bank_->HasNight(view) && attempt < 8; ++attempt) {
    view = static_cast<uint32_t>(random.UniformInt(bank_->NumViews()));
  }
  return night && bank_->HasNight(view) ? bank_->night().row(view).transpose()
                                        : bank_->day().row(view).transpose();
}

SyntheticViewFeatures SyntheticCity::MakeViewFeatures(const SyntheticView& view,
                                                      QueryCondition condition,
                                                      uint64_t view_key) const {
  const bool night = condition == QueryCondition::kNight;
  Random random(options_.seed, {kStreamViewFeatures, view_key});
  const int max_keypoints = options_.max_keypoints_per_image;
  const int clutter = std::min(
      night ? options_.night_clutter_per_image : options_.clutter_per_image, max_keypoints / 4);
  const std::vector<uint32_t> detected =
      DetectedPoints(view, night, static_cast<size_t>(max_keypoints - clutter), random);

  // Detections first, then clutter; a random permutation then mixes them as a detector would.
  const size_t num_keypoints = detected.size() + clutter;
  std::vector<int64_t> source(num_keypoints, -1);
  std::copy(detected.begin(), detected.end(), source.begin());
  for (size_t i = num_keypoints; i > 1; --i) std::swap(source[i - 1], source[random.UniformInt(i)]);

  const Eigen::Vector3d center = CameraCenterInWorld(view.cam_from_world);
  SyntheticViewFeatures result;
  result.features.keypoints.resize(num_keypoints, 2);
  result.features.descriptors.resize(num_keypoints, options_.descriptor_dim);
  result.point_of_keypoint = source;
  for (size_t k = 0; k < num_keypoints; ++k) {
    Eigen::Vector2d pixel;
    Eigen::VectorXf descriptor;
    if (source[k] >= 0) {
      const auto p = static_cast<uint32_t>(source[k]);
      pixel = view.camera.ImgFromPointInCam(view.cam_from_world * points_[p]);
      pixel += options_.keypoint_noise_px * Eigen::Vector2d(random.Normal(), random.Normal());
      descriptor = ObservedDescriptor(p, center, night, random);
    } else {
      pixel = Eigen::Vector2d(random.Uniform(0, view.camera.width),
                              random.Uniform(0, view.camera.height));
      descriptor = ClutterDescriptor(night, random);
    }
    pixel.x() = std::clamp(pixel.x(), 0.0, static_cast<double>(view.camera.width));
    pixel.y() = std::clamp(pixel.y(), 0.0, static_cast<double>(view.camera.height));
    result.features.keypoints.row(k) = pixel.cast<float>().transpose();
    result.features.descriptors.row(k) = descriptor.transpose();
  }
  return result;
}

}  // namespace hscloc
