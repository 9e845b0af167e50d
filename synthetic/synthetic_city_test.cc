#include "synthetic/synthetic_city.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>

#include "scene/colmap_io.h"
#include "scene/descriptor_bank_test_support.h"
#include "scene/feature_io.h"
#include "synthetic/synthetic_city_writer.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

std::string CheckMessage(const SyntheticCityOptions& options) {
  try {
    options.Check();
  } catch (const std::invalid_argument& error) {
    return error.what();
  }
  return "";
}

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream stream(path, std::ios::binary);
  std::stringstream buffer;
  buffer << stream.rdbuf();
  return buffer.str();
}

SyntheticCityWriteOptions QuietWrite() {
  SyntheticCityWriteOptions options;
  options.show_progress = false;
  return options;
}

TEST(SyntheticCityOptions, PresetsAreValid) {
  for (const std::string& name : SyntheticCityOptions::PresetNames()) {
    EXPECT_NO_THROW(SyntheticCityOptions::Preset(name).Check()) << name;
  }
  EXPECT_THROW(SyntheticCityOptions::Preset("megacity"), std::invalid_argument);
}

TEST(SyntheticCityOptions, CheckNamesTheBadField) {
  const SyntheticCityOptions valid = SyntheticCityOptions::Preset("tiny");
  struct Case {
    std::function<void(SyntheticCityOptions&)> breaks;
    std::string field;
  };
  const std::vector<Case> cases = {
      {[](auto& o) { o.blocks_x = 0; }, "blocks_x"},
      {[](auto& o) { o.block_size_m = -1; }, "block_size_m"},
      {[](auto& o) { o.street_width_m = 1; }, "street_width_m"},
      {[](auto& o) { o.building_height_min_m = 30; }, "building_height_min_m"},
      {[](auto& o) { o.facade_points_per_m2 = 0; }, "facade_points_per_m2"},
      {[](auto& o) { o.headings_per_stop = 9; }, "headings_per_stop"},
      {[](auto& o) { o.focal_max_px = 10; }, "focal_min_px"},
      {[](auto& o) { o.descriptor_dim = 1; }, "descriptor_dim"},
      {[](auto& o) { o.repeated_fraction = 1.5; }, "repeated_fraction"},
      {[](auto& o) { o.night_detection_rate = 0; }, "night_detection_rate"},
      {[](auto& o) { o.keypoint_noise_px = -0.1; }, "keypoint_noise_px"},
      {[](auto& o) { o.max_keypoints_per_image = 3; }, "max_keypoints_per_image"},
      {[](auto& o) { o.lateral_jitter_m = 50; }, "lateral_jitter_m"},
  };
  for (const Case& test_case : cases) {
    SyntheticCityOptions options = valid;
    test_case.breaks(options);
    EXPECT_THAT(CheckMessage(options), HasSubstr(test_case.field));
  }
  SyntheticCityOptions options = valid;
  options.blocks_x = -3;
  EXPECT_THROW(SyntheticCity city(options), std::invalid_argument);
}

TEST(SyntheticCity, LaysOutPointsOnFacadesAndGround) {
  const SyntheticCity city(SyntheticCityOptions::Preset("tiny"));
  ASSERT_EQ(city.blocks().size(), 4u);
  ASSERT_GT(city.points().size(), 500u);
  ASSERT_EQ(city.point_normals().size(), city.points().size());
  for (size_t p = 0; p < city.points().size(); ++p) {
    const Eigen::Vector3d& point = city.points()[p];
    const int block = city.point_blocks()[p];
    if (block < 0) {
      EXPECT_EQ(point.z(), 0.0);
      continue;
    }
    const Eigen::AlignedBox3d& box = city.blocks()[block];
    // On the box surface: inside the closed box, outside the open one along its normal.
    EXPECT_TRUE(box.contains(point)) << p;
    EXPECT_FALSE(box.contains(point + 0.01 * city.point_normals()[p])) << p;
  }
  EXPECT_GT(city.database_views().size(), 30u);
  EXPECT_EQ(city.queries(QueryCondition::kDay).size(), 6u);
  EXPECT_EQ(city.queries(QueryCondition::kNight).size(), 6u);
}

TEST(SyntheticCity, SegmentsThroughBuildingsAreBlocked) {
  const SyntheticCity city(SyntheticCityOptions::Preset("tiny"));
  const Eigen::AlignedBox3d& box = city.blocks()[0];
  const Eigen::Vector3d center = box.center();
  const Eigen::Vector3d west(box.min().x() - 3, center.y(), 1.6);
  const Eigen::Vector3d east(box.max().x() + 3, center.y(), 1.6);
  EXPECT_FALSE(city.IsSegmentFree(west, east));
  // Along the street in front of the block, and over its roof.
  EXPECT_TRUE(city.IsSegmentFree(west, Eigen::Vector3d(west.x(), box.max().y(), 1.6)));
  EXPECT_TRUE(city.IsSegmentFree(Eigen::Vector3d(west.x(), center.y(), box.max().z() + 1),
                                 Eigen::Vector3d(east.x(), center.y(), box.max().z() + 1)));
}

TEST(SyntheticCity, ViewsSeeUnoccludedFacingPointsInsideTheImage) {
  const SyntheticCity city(SyntheticCityOptions::Preset("tiny"));
  size_t total = 0;
  for (const SyntheticView& view : city.database_views()) {
    const Eigen::Vector3d center = CameraCenterInWorld(view.cam_from_world);
    for (const uint32_t p : city.VisiblePoints(view.camera, view.cam_from_world)) {
      const Eigen::Vector3d& point = city.points()[p];
      ASSERT_GT((view.cam_from_world * point).z(), 0.0);
      ASSERT_TRUE(view.camera.IsInside(view.camera.ImgFromPointInCam(view.cam_from_world * point)));
      ASSERT_GT(city.point_normals()[p].dot(center - point), 0.0);
      ASSERT_LE((center - point).norm(), city.options().max_range_m);
      ++total;
    }
  }
  EXPECT_GT(total / city.database_views().size(), 20u);
}

TEST(SyntheticCity, NightDetectsFewerPointsWithMoreClutter) {
  const SyntheticCity city(SyntheticCityOptions::Preset("tiny"));
  const SyntheticView& view = city.queries(QueryCondition::kDay)[0];
  const SyntheticViewFeatures day = city.MakeViewFeatures(view, QueryCondition::kDay, 1);
  const SyntheticViewFeatures night = city.MakeViewFeatures(view, QueryCondition::kNight, 1);
  auto count_points = [](const SyntheticViewFeatures& features) {
    return std::count_if(features.point_of_keypoint.begin(), features.point_of_keypoint.end(),
                         [](int64_t p) { return p >= 0; });
  };
  auto mean_cosine = [&](const SyntheticViewFeatures& made) {
    double sum = 0;
    int count = 0;
    for (size_t k = 0; k < made.point_of_keypoint.size(); ++k) {
      if (made.point_of_keypoint[k] < 0) continue;
      sum += made.features.descriptors.row(k).dot(
          city.PointDescriptor(static_cast<uint32_t>(made.point_of_keypoint[k])).transpose());
      ++count;
    }
    return sum / count;
  };
  EXPECT_LT(count_points(night), count_points(day));
  EXPECT_GT(night.point_of_keypoint.size() - count_points(night),
            day.point_of_keypoint.size() - count_points(day));
  EXPECT_LT(mean_cosine(night), mean_cosine(day) - 0.1);
  // Unit descriptors, as SuperPoint's.
  for (int k = 0; k < night.features.descriptors.rows(); ++k) {
    ASSERT_NEAR(night.features.descriptors.row(k).norm(), 1.0, 1e-5);
  }
}

// The configured share of points copies the appearance of a point on another building, and those
// points are the ones a plain nearest-neighbour match gets wrong.
TEST(SyntheticCity, RepeatedStructureMakesDescriptorsAmbiguous) {
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.repeated_fraction = 0.3;
  const SyntheticCity city(options);
  const auto& appearance = city.appearance_of_point();
  size_t copies = 0;
  for (size_t p = 0; p < appearance.size(); ++p) {
    if (appearance[p] == p) continue;
    ++copies;
    EXPECT_NE(city.point_blocks()[appearance[p]], city.point_blocks()[p]);
    EXPECT_TRUE(city.PointDescriptor(p).isApprox(city.PointDescriptor(appearance[p])));
  }
  const double share = static_cast<double>(copies) / appearance.size();
  EXPECT_NEAR(share, options.repeated_fraction, 0.04);

  // Database descriptors, labelled with their point.
  std::vector<Eigen::VectorXf> database;
  std::vector<int64_t> database_point;
  for (size_t i = 0; i < city.database_views().size(); ++i) {
    const SyntheticViewFeatures made =
        city.MakeViewFeatures(city.database_views()[i], QueryCondition::kDay, i);
    for (size_t k = 0; k < made.point_of_keypoint.size(); ++k) {
      if (made.point_of_keypoint[k] < 0) continue;
      database.push_back(made.features.descriptors.row(k).transpose());
      database_point.push_back(made.point_of_keypoint[k]);
    }
  }
  std::set<int64_t> shared_appearance;  // points whose appearance another point also has
  for (size_t p = 0; p < appearance.size(); ++p) {
    if (appearance[p] != p) {
      shared_appearance.insert(p);
      shared_appearance.insert(appearance[p]);
    }
  }
  int wrong_shared = 0, total_shared = 0, wrong_unique = 0, total_unique = 0;
  for (size_t q = 0; q < city.queries(QueryCondition::kDay).size(); ++q) {
    const SyntheticViewFeatures made = city.MakeViewFeatures(city.queries(QueryCondition::kDay)[q],
                                                             QueryCondition::kDay, 1000 + q);
    for (size_t k = 0; k < made.point_of_keypoint.size(); ++k) {
      const int64_t point = made.point_of_keypoint[k];
      if (point < 0) continue;
      const bool point_in_database =
          std::find(database_point.begin(), database_point.end(), point) != database_point.end();
      if (!point_in_database) continue;
      size_t best = 0;
      float best_score = -2;
      for (size_t d = 0; d < database.size(); ++d) {
        const float score = made.features.descriptors.row(k).dot(database[d].transpose());
        if (score > best_score) {
          best_score = score;
          best = d;
        }
      }
      const bool wrong = database_point[best] != point;
      if (shared_appearance.count(point)) {
        wrong_shared += wrong;
        ++total_shared;
      } else {
        wrong_unique += wrong;
        ++total_unique;
      }
    }
  }
  ASSERT_GT(total_shared, 50);
  ASSERT_GT(total_unique, 50);
  EXPECT_GT(static_cast<double>(wrong_shared) / total_shared, 0.25);
  EXPECT_LT(static_cast<double>(wrong_unique) / total_unique, 0.05);
}

TEST(SyntheticCityWriter, WritesAModelOurReaderAndTheFeaturesAgreeOn) {
  testing::TempDir temp;
  const SyntheticCity city(SyntheticCityOptions::Preset("tiny"));
  const SyntheticCityStats stats = WriteSyntheticCity(city, temp / "city", QuietWrite());
  EXPECT_FALSE(std::filesystem::exists(temp / "city.partial"));

  const Reconstruction map = ReadColmapModel(temp / "city" / "map");
  EXPECT_EQ(map.images.size(), city.database_views().size());
  EXPECT_EQ(map.points3D.size(), stats.num_map_points);
  EXPECT_EQ(map.NumObservations(), stats.num_database_observations);
  EXPECT_GT(stats.num_map_points, 300u);

  // Every observation reprojects within the keypoint noise (5 sigma per axis, both axes).
  const double bound = 5 * std::sqrt(2.0) * city.options().keypoint_noise_px;
  for (const auto& [point3D_id, point] : map.points3D) {
    ASSERT_GE(static_cast<int>(point.track.size()), city.options().min_track_length);
    for (const TrackElement& element : point.track) {
      const Image& image = map.images.at(element.image_id);
      const Camera& camera = map.cameras.at(image.camera_id);
      const Eigen::Vector2d projected = camera.ImgFromPointInCam(image.cam_from_world * point.xyz);
      ASSERT_LT((projected - image.points2D[element.point2D_idx].xy).norm(), bound)
          << image.name << " point " << point3D_id;
    }
  }

  // The features file holds every database keypoint where the model says it is.
  const auto features = OpenFeatureReader(temp / "city" / "features.h5");
  const Observations observations = JoinObservations(map, *features);
  EXPECT_EQ(observations.size(), map.NumObservations());
  EXPECT_EQ(observations.Dimension(), city.options().descriptor_dim);
  EXPECT_TRUE(features->HasImage(city.queries(QueryCondition::kNight)[0].name));

  std::ifstream day_list(temp / "city" / "queries" / "day_time_queries_with_intrinsics.txt");
  std::string name, model;
  day_list >> name >> model;
  EXPECT_EQ(name, city.queries(QueryCondition::kDay)[0].name);
  EXPECT_EQ(model, "SIMPLE_RADIAL");
}

TEST(SyntheticCityWriter, SameSeedGivesIdenticalFiles) {
  testing::TempDir temp;
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.num_day_queries = 2;
  options.num_night_queries = 2;
  WriteSyntheticCity(SyntheticCity(options), temp / "a", QuietWrite());
  SyntheticCityWriteOptions two_threads = QuietWrite();
  two_threads.num_threads = 2;
  WriteSyntheticCity(SyntheticCity(options), temp / "b", two_threads);
  options.seed = 1;
  WriteSyntheticCity(SyntheticCity(options), temp / "c", QuietWrite());
  for (const char* file : {"map/cameras.bin", "map/images.bin", "map/points3D.bin", "features.h5",
                           "queries_gt.txt", "queries/point3D_ids.txt", "stats.json"}) {
    EXPECT_EQ(ReadFile(temp / "a" / file), ReadFile(temp / "b" / file)) << file;
  }
  EXPECT_NE(ReadFile(temp / "a" / "map/points3D.bin"), ReadFile(temp / "c" / "map/points3D.bin"));
}

TEST(SyntheticCityWriter, QueryPointIdsNameMapPointsTheKeypointsSee) {
  testing::TempDir temp;
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.num_day_queries = 3;
  options.num_night_queries = 0;
  const SyntheticCity city(options);
  WriteSyntheticCity(city, temp / "city", QuietWrite());
  const Reconstruction map = ReadColmapModel(temp / "city" / "map");
  const auto features = OpenH5Features(temp / "city" / "features.h5");
  std::ifstream file(temp / "city" / "queries" / "point3D_ids.txt");
  size_t in_map = 0;
  size_t line_number = 0;
  for (std::string line; std::getline(file, line); ++line_number) {
    std::istringstream fields(line);
    std::string name;
    fields >> name;
    const SyntheticView& view = city.queries(QueryCondition::kDay).at(line_number);
    ASSERT_EQ(name, view.name);
    const ImageFeatures query = features->Read(name);
    int64_t keypoint = 0;
    for (int64_t id; fields >> id; ++keypoint) {
      if (id < 0) continue;
      ++in_map;
      // The id is a map point, and the keypoint lies at its projection (plus detection noise).
      const auto point = map.points3D.find(static_cast<point3D_t>(id));
      ASSERT_NE(point, map.points3D.end()) << name << " keypoint " << keypoint;
      const Eigen::Vector2d projection =
          view.camera.ImgFromPointInCam(view.cam_from_world * point->second.xyz);
      EXPECT_LT((projection - query.keypoints.row(keypoint).transpose().cast<double>()).norm(), 3)
          << name << " keypoint " << keypoint;
    }
    EXPECT_EQ(keypoint, query.NumKeypoints()) << name;
  }
  EXPECT_EQ(line_number, 3u);
  EXPECT_GT(in_map, 100u);
}

TEST(SyntheticCityWriter, RefusesToOverwriteUnlessAsked) {
  testing::TempDir temp;
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.num_day_queries = 1;
  options.num_night_queries = 1;
  const SyntheticCity city(options);
  std::filesystem::create_directories(temp / "city");
  EXPECT_THROW(WriteSyntheticCity(city, temp / "city", QuietWrite()), std::invalid_argument);
  SyntheticCityWriteOptions overwrite = QuietWrite();
  overwrite.overwrite = true;
  EXPECT_NO_THROW(WriteSyntheticCity(city, temp / "city", overwrite));
  EXPECT_TRUE(std::filesystem::exists(temp / "city" / "map" / "points3D.bin"));
}

TEST(SyntheticCityWriter, ColmapAcceptsTheModel) {
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir temp;
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.num_day_queries = 1;
  options.num_night_queries = 1;
  const SyntheticCityStats stats =
      WriteSyntheticCity(SyntheticCity(options), temp / "city", QuietWrite());
  const std::string log = (temp / "analyzer.log").string();
  ASSERT_EQ(testing::RunCommand(
                colmap + " model_analyzer --path " + (temp / "city" / "map").string(), log),
            0);
  const std::string output = ReadFile(log);
  EXPECT_THAT(output, HasSubstr("Points: " + std::to_string(stats.num_map_points)));
  EXPECT_THAT(output, HasSubstr("Registered images: " + std::to_string(stats.num_database_images)));
}

std::shared_ptr<const DescriptorBank> RandomBank(int tracks, int dim, uint64_t seed) {
  return std::make_shared<const DescriptorBank>(
      testing::RandomDescriptorBank(tracks, dim, seed, 2));
}

// Whether `row` is one of `rows`, exactly.
bool IsRowOf(const Eigen::RowVectorXf& row, const DescriptorMatrix& rows, int64_t first,
             int64_t end) {
  for (int64_t i = first; i < end; ++i) {
    if (rows.row(i) == row) return true;
  }
  return false;
}

TEST(SyntheticCityRealAppearance, EveryDetectionIsARealViewOfItsPointsTrack) {
  const auto bank = RandomBank(300, 16, 1);
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.bank_view_noise = 0;
  const SyntheticCity city(options, bank);
  options.bank_view_noise = 0.2;
  const SyntheticCity noisy(options, bank);
  EXPECT_EQ(city.options().descriptor_dim, 16);
  size_t detections = 0;
  for (size_t i = 0; i < 3; ++i) {
    const SyntheticView& view = city.database_views()[i];
    const SyntheticViewFeatures made = city.MakeViewFeatures(view, QueryCondition::kDay, i);
    const SyntheticViewFeatures noisy_made = noisy.MakeViewFeatures(view, QueryCondition::kDay, i);
    const Eigen::Vector3d center = CameraCenterInWorld(view.cam_from_world);
    for (size_t k = 0; k < made.point_of_keypoint.size(); ++k) {
      const Eigen::RowVectorXf descriptor = made.features.descriptors.row(k);
      if (made.point_of_keypoint[k] < 0) {
        // Clutter: some view's descriptor too, never a random vector.
        EXPECT_TRUE(IsRowOf(descriptor, bank->day(), 0, bank->day().rows()));
        continue;
      }
      const auto p = static_cast<uint32_t>(made.point_of_keypoint[k]);
      const uint32_t track = city.TrackOfPoint(p);
      const uint32_t chosen = city.BankViewOfPoint(p, center);
      ASSERT_GE(chosen, bank->FirstView(track));
      ASSERT_LT(chosen, bank->EndView(track));
      if (city.appearance_of_point()[p] < bank->NumTracks()) {
        // A track's first use: the chosen view's descriptor itself, or near it with view noise.
        EXPECT_EQ(descriptor, bank->day().row(chosen));
        ASSERT_EQ(noisy_made.point_of_keypoint[k], made.point_of_keypoint[k]);
        const Eigen::RowVectorXf blurred = noisy_made.features.descriptors.row(k);
        EXPECT_NE(blurred, bank->day().row(chosen));
        EXPECT_GT(blurred.dot(bank->day().row(chosen)), 0.85f);
      } else {
        EXPECT_NEAR(descriptor.norm(), 1.0f, 1e-5f);
      }
      ++detections;
    }
  }
  EXPECT_GT(detections, 50u);
}

TEST(SyntheticCityRealAppearance, NightDescriptorsOnlyInNightQueries) {
  const auto bank = RandomBank(300, 16, 2);
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  const SyntheticCity city(options, bank);
  const auto count_night_rows = [&](const SyntheticViewFeatures& made) {
    size_t night = 0;
    for (int64_t k = 0; k < made.features.descriptors.rows(); ++k) {
      night += IsRowOf(made.features.descriptors.row(k), bank->night(), 0, bank->night().rows());
    }
    return night;
  };
  size_t night_in_day = 0, night_in_night = 0, detections_at_night = 0;
  for (size_t i = 0; i < 2; ++i) {
    night_in_day +=
        count_night_rows(city.MakeViewFeatures(city.database_views()[i], QueryCondition::kDay, i));
    night_in_day += count_night_rows(city.MakeViewFeatures(city.queries(QueryCondition::kDay)[i],
                                                           QueryCondition::kDay, 100 + i));
    const SyntheticView& view = city.queries(QueryCondition::kNight)[i];
    const SyntheticViewFeatures night =
        city.MakeViewFeatures(view, QueryCondition::kNight, 200 + i);
    night_in_night += count_night_rows(night);
    // A night detection is of a view found again at night.
    const Eigen::Vector3d center = CameraCenterInWorld(view.cam_from_world);
    for (const int64_t p : night.point_of_keypoint) {
      if (p < 0) continue;
      EXPECT_TRUE(bank->HasNight(city.BankViewOfPoint(static_cast<uint32_t>(p), center)));
      ++detections_at_night;
    }
  }
  EXPECT_EQ(night_in_day, 0u);
  EXPECT_GT(detections_at_night, 20u);
  EXPECT_GE(night_in_night, detections_at_night / 2);
}

TEST(SyntheticCityRealAppearance, TheSameSeedAndBankGiveTheSameCity) {
  const auto bank = RandomBank(200, 8, 3);
  SyntheticCityOptions options = SyntheticCityOptions::Preset("tiny");
  options.bank_reuse_noise = 0.3;
  const SyntheticCity a(options, bank), b(options, bank);
  options.seed = 9;
  const SyntheticCity other(options, bank);
  const SyntheticView& view = a.database_views()[0];
  const SyntheticViewFeatures made_a = a.MakeViewFeatures(view, QueryCondition::kDay, 5);
  const SyntheticViewFeatures made_b = b.MakeViewFeatures(view, QueryCondition::kDay, 5);
  EXPECT_EQ(made_a.features.descriptors, made_b.features.descriptors);
  EXPECT_EQ(made_a.features.keypoints, made_b.features.keypoints);
  // Another seed deals the tracks out differently.
  size_t same_track = 0;
  for (uint32_t p = 0; p < 200; ++p) same_track += a.TrackOfPoint(p) == other.TrackOfPoint(p);
  EXPECT_LT(same_track, 20u);
  // A bank without tracks is refused.
  EXPECT_THROW(
      SyntheticCity(options, std::make_shared<const DescriptorBank>(
                                 "xfeat", std::vector<std::string>{}, std::vector<uint32_t>{0},
                                 DescriptorMatrix(0, 8), ViewDirectionMatrix(0, 3),
                                 DescriptorMatrix(0, 8), std::vector<uint8_t>{})),
      std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
