#include "bank/bank_builder.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <unordered_map>

#include "features/image_extraction.h"
#include "scene/colmap_io.h"
#include "util/check.h"
#include "util/logging.h"
#include "util/random.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// The world's up as the set's photos show it: the mean of the cameras' up vectors (-y of a COLMAP
// camera), since an SfM frame has no up of its own and street photos are taken upright.
Eigen::Vector3d MeanCameraUp(const Reconstruction& reconstruction) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const auto& [id, image] : reconstruction.images) {
    sum += image.cam_from_world.rotation.inverse() * Eigen::Vector3d(0, -1, 0);
  }
  return sum.norm() > 1e-9 ? sum.normalized() : Eigen::Vector3d::UnitZ();
}

// The row of the keypoint of `keypoints` nearest `pixel`, when within `max_px`; -1 otherwise.
int64_t NearestKeypoint(const KeypointMatrix& keypoints, const Eigen::Vector2f& pixel,
                        double max_px) {
  int64_t best = -1;
  float best_squared = static_cast<float>(max_px * max_px);
  for (int64_t i = 0; i < keypoints.rows(); ++i) {
    const float squared = (keypoints.row(i).transpose() - pixel).squaredNorm();
    if (squared <= best_squared) {
      best_squared = squared;
      best = i;
    }
  }
  return best;
}

// The features of every image of the reconstruction, read once.
std::unordered_map<image_t, ImageFeatures> ReadAllFeatures(const Reconstruction& reconstruction,
                                                           const FeatureReader& reader) {
  std::unordered_map<image_t, ImageFeatures> features;
  for (const auto& [id, image] : reconstruction.images) features[id] = reader.Read(image.name);
  return features;
}

}  // namespace

void NightTransformOptions::Check() const {
  THROW_CHECK_MSG(exposure_min > 0 && exposure_min <= exposure_max && exposure_max <= 1,
                  "night exposure range must lie in (0, 1] (got {} to {})", exposure_min,
                  exposure_max);
  THROW_CHECK_MSG(gamma_min >= 1 && gamma_min <= gamma_max,
                  "night gamma range must start at 1 "
                  "or above (got {} to {})",
                  gamma_min, gamma_max);
  THROW_CHECK_MSG(blue_gain > 0 && blue_gain <= 1 && green_gain > 0 && green_gain <= 1,
                  "night colour gains must lie in (0, 1] (got blue {}, green {})", blue_gain,
                  green_gain);
  THROW_CHECK_MSG(noise_sigma >= 0 && blur_sigma_max_px >= 0,
                  "night noise and blur must be >= 0 (got {}, {})", noise_sigma, blur_sigma_max_px);
  THROW_CHECK_MSG(jpeg_quality >= 1 && jpeg_quality <= 100,
                  "night JPEG quality must lie in 1..100 (got {})", jpeg_quality);
}

cv::Mat NightPhoto(const cv::Mat& bgr, const NightTransformOptions& options, uint64_t key) {
  options.Check();
  if (bgr.empty() || bgr.type() != CV_8UC3) {
    ThrowInvalidArgument("a night photo needs an 8-bit colour image");
  }
  Random random(key, {0x6e696768u});
  const double exposure = random.Uniform(options.exposure_min, options.exposure_max);
  const double gamma = random.Uniform(options.gamma_min, options.gamma_max);
  const double blur = random.Uniform(0.3, std::max(0.3, options.blur_sigma_max_px));
  cv::Mat light;
  bgr.convertTo(light, CV_32FC3, 1.0 / 255.0);
  cv::multiply(light,
               cv::Scalar(exposure * options.blue_gain, exposure * options.green_gain, exposure),
               light);
  cv::Mat noise(light.size(), CV_32FC3);
  cv::RNG rng(random.NextU64());
  rng.fill(noise, cv::RNG::NORMAL, 0.0, options.noise_sigma);
  light += noise;
  cv::max(light, 0.0, light);
  cv::min(light, 1.0, light);
  cv::pow(light, 1.0 / gamma, light);
  cv::GaussianBlur(light, light, cv::Size(0, 0), blur);
  cv::Mat night;
  light.convertTo(night, CV_8UC3, 255.0);
  std::vector<uchar> jpeg;
  cv::imencode(".jpg", night, jpeg, {cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality});
  return cv::imdecode(jpeg, cv::IMREAD_COLOR);
}

DescriptorBank BankFromReconstruction(const Reconstruction& reconstruction,
                                      const FeatureReader& day, const FeatureReader* night,
                                      double night_match_px, int min_track_length,
                                      const std::string& feature, const std::string& source) {
  const Eigen::Vector3d up = MeanCameraUp(reconstruction);
  const auto day_features = ReadAllFeatures(reconstruction, day);
  std::unordered_map<image_t, ImageFeatures> night_features;
  if (night != nullptr) night_features = ReadAllFeatures(reconstruction, *night);
  std::unordered_map<image_t, Eigen::Vector3d> centers;
  for (const auto& [id, image] : reconstruction.images) {
    centers[id] = CameraCenterInWorld(image.cam_from_world);
  }
  int64_t dim = 0;
  for (const auto& [id, features] : day_features) dim = std::max(dim, features.descriptors.cols());
  std::vector<uint32_t> offsets = {0};
  std::vector<Eigen::VectorXf> day_rows, night_rows;
  std::vector<Eigen::Vector3f> directions;
  std::vector<uint8_t> has_night;
  for (const auto& [point_id, point] : reconstruction.points3D) {
    if (static_cast<int>(point.track.size()) < min_track_length) continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const TrackElement& element : point.track) {
      mean += (centers.at(element.image_id) - point.xyz).normalized();
    }
    for (const TrackElement& element : point.track) {
      const ImageFeatures& features = day_features.at(element.image_id);
      const Eigen::VectorXf descriptor = features.descriptors.row(element.point2D_idx).transpose();
      day_rows.push_back(descriptor.normalized());
      directions.push_back(
          LocalViewDirection(centers.at(element.image_id) - point.xyz, mean, up).normalized());
      int64_t night_row = -1;
      if (night != nullptr) {
        const ImageFeatures& dark = night_features.at(element.image_id);
        night_row =
            NearestKeypoint(dark.keypoints, features.keypoints.row(element.point2D_idx).transpose(),
                            night_match_px);
        if (night_row >= 0) {
          night_rows.push_back(dark.descriptors.row(night_row).transpose().normalized());
        }
      }
      if (night_row < 0) night_rows.push_back(Eigen::VectorXf::Zero(dim));
      has_night.push_back(night_row >= 0);
    }
    offsets.push_back(static_cast<uint32_t>(day_rows.size()));
  }
  const auto views = static_cast<int64_t>(day_rows.size());
  DescriptorMatrix day_matrix(views, dim), night_matrix(views, dim);
  ViewDirectionMatrix direction_matrix(views, 3);
  for (int64_t i = 0; i < views; ++i) {
    day_matrix.row(i) = day_rows[i].transpose();
    night_matrix.row(i) = night_rows[i].transpose();
    direction_matrix.row(i) = directions[i].transpose();
  }
  return DescriptorBank(feature, {source}, std::move(offsets), std::move(day_matrix),
                        std::move(direction_matrix), std::move(night_matrix), std::move(has_night));
}

void BankSetOptions::Check() const {
  extractor.Check();
  triangulation.Check();
  night.Check();
  THROW_CHECK_MSG(night_match_px > 0, "night_match_px must be > 0 (got {})", night_match_px);
  THROW_CHECK_MSG(min_track_length >= 1, "min_track_length must be >= 1 (got {})",
                  min_track_length);
}

DescriptorBank BankFromSet(const fs::path& set_dir, const fs::path& work_dir,
                           const BankSetOptions& options) {
  options.Check();
  const fs::path images = set_dir / "images";
  const fs::path model = set_dir / "map";
  if (!fs::is_directory(images) || !fs::is_directory(model)) {
    ThrowInvalidArgument(
        "{} is not a real set: it needs images/ (photos) and map/ (a COLMAP "
        "model of the map photos with their poses)",
        set_dir.string());
  }
  fs::create_directories(work_dir);
  const std::string feature = FeatureTypeName(options.extractor.type);
  const Reconstruction posed = ReadColmapModel(model);
  std::vector<std::string> names;
  for (const auto& [id, image] : posed.images) names.push_back(image.name);
  std::sort(names.begin(), names.end());

  ImageExtractionOptions extraction;
  extraction.extractor = options.extractor;
  extraction.show_progress = options.show_progress;
  const fs::path day_features = work_dir / fmt::format("{}.h5", feature);
  ExtractImagesToH5(images, names, day_features, extraction);

  const fs::path triangulated = work_dir / "model";
  MapTriangulationOptions triangulation = options.triangulation;
  triangulation.show_progress = options.show_progress;
  if (!fs::exists(triangulated / "points3D.bin")) {
    TriangulateMap({model, day_features, images}, triangulation, triangulated);
  }

  // The night photos, written once; their features are extracted like the day's.
  const fs::path night_images = work_dir / "night_images";
  for (size_t i = 0; i < names.size(); ++i) {
    const fs::path out = night_images / names[i];
    if (fs::exists(out)) continue;
    const cv::Mat photo = cv::imread((images / names[i]).string(), cv::IMREAD_COLOR);
    if (photo.empty())
      ThrowInvalidArgument("cannot read the photo {}", (images / names[i]).string());
    fs::create_directories(out.parent_path());
    // Stored losslessly (the transform's own JPEG step is the night photo's compression) under
    // the day photo's name, so that the night features are found by the same image names; the
    // reader goes by the file's content, not its extension.
    const std::string partial = out.string() + ".partial.png";
    cv::imwrite(partial, NightPhoto(photo, options.night, MixBits(i)));
    fs::rename(partial, out);
  }
  const fs::path night_features = work_dir / fmt::format("{}-night.h5", feature);
  ExtractImagesToH5(night_images, names, night_features, extraction);

  const auto day = OpenFeatureReader(day_features);
  const auto night = OpenFeatureReader(night_features);
  return BankFromReconstruction(ReadColmapModel(triangulated), *day, night.get(),
                                options.night_match_px, options.min_track_length, feature,
                                BankSetName(set_dir));
}

std::string BankSetName(const fs::path& set_dir) {
  fs::path normal = fs::absolute(set_dir).lexically_normal();
  if (normal.filename().empty()) normal = normal.parent_path();
  return normal.filename().string();
}

DescriptorBank BankFromSets(const std::vector<fs::path>& set_dirs, const fs::path& work_dir,
                            const BankSetOptions& options, const BankSetDone& done) {
  std::vector<DescriptorBank> banks;
  for (size_t i = 0; i < set_dirs.size(); ++i) {
    const Timer timer;
    const fs::path work = work_dir / fmt::format("{}-{}", i + 1, BankSetName(set_dirs[i]));
    banks.push_back(BankFromSet(set_dirs[i], work, options));
    if (done) done(set_dirs[i], banks.back(), timer.ElapsedSeconds());
  }
  DescriptorBank bank = DescriptorBank::Concatenate(banks);
  if (bank.NumTracks() == 0) ThrowInvalidArgument("the sets hold no track of two or more views");
  return bank;
}

}  // namespace hscloc
