#include "scene/feature_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <random>

#include "scene/colmap_io.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

ImageFeatures RandomFeatures(int num_keypoints, int dimension, std::mt19937* random) {
  std::uniform_real_distribution<float> coordinate(0.5f, 639.5f), value(0.f, 1.f);
  ImageFeatures features;
  features.keypoints.resize(num_keypoints, 2);
  features.descriptors.resize(num_keypoints, dimension);
  for (int i = 0; i < num_keypoints; ++i) {
    features.keypoints.row(i) << coordinate(*random), coordinate(*random);
    for (int d = 0; d < dimension; ++d) features.descriptors(i, d) = value(*random);
  }
  return features;
}

// An image whose 2D points sit exactly on `features`' keypoints; `observed` (index, point3D id)
// gives the ones with a 3D point.
Image ImageOn(image_t image_id, const std::string& name, const ImageFeatures& features,
              const std::vector<std::pair<point2D_t, point3D_t>>& observed) {
  Image image;
  image.image_id = image_id;
  image.name = name;
  image.camera_id = 1;
  image.points2D.resize(features.NumKeypoints());
  for (int64_t i = 0; i < features.NumKeypoints(); ++i) {
    image.points2D[i].xy = features.keypoints.row(i).transpose().cast<double>();
  }
  for (const auto& [idx, point3D_id] : observed) image.points2D[idx].point3D_id = point3D_id;
  return image;
}

// Two images, ids deliberately out of name order, written to an .h5 file.
class SyntheticJoin : public ::testing::Test {
 protected:
  void SetUp() override {
    std::mt19937 random(21);
    features_a_ = RandomFeatures(20, 16, &random);
    features_b_ = RandomFeatures(12, 16, &random);
    reconstruction_.images[7] = ImageOn(7, "a.jpg", features_a_, {{3, 100}, {1, 101}, {19, 102}});
    reconstruction_.images[2] = ImageOn(2, "sub/b.jpg", features_b_, {{11, 100}, {0, 103}});
    H5FeatureWriter writer(dir_ / "features.h5", H5FloatPrecision::kFloat32);
    writer.Write("a.jpg", features_a_, 640, 640);
    writer.Write("sub/b.jpg", features_b_, 640, 640);
    writer.Close();
  }

  testing::TempDir dir_;
  ImageFeatures features_a_, features_b_;
  Reconstruction reconstruction_;
};

TEST_F(SyntheticJoin, RowsFollowImageIdThenKeypointIndex) {
  const Observations observations =
      JoinObservations(reconstruction_, *OpenH5Features(dir_ / "features.h5"));
  ASSERT_EQ(observations.size(), 5u);
  EXPECT_THAT(observations.image_ids, ::testing::ElementsAre(2, 2, 7, 7, 7));
  EXPECT_THAT(observations.keypoint_indices, ::testing::ElementsAre(0, 11, 1, 3, 19));
  EXPECT_THAT(observations.point3D_ids, ::testing::ElementsAre(103, 100, 101, 100, 102));
  ASSERT_EQ(observations.Dimension(), 16);
  EXPECT_EQ(observations.descriptors.row(0), features_b_.descriptors.row(0));
  EXPECT_EQ(observations.descriptors.row(1), features_b_.descriptors.row(11));
  EXPECT_EQ(observations.descriptors.row(4), features_a_.descriptors.row(19));
}

TEST_F(SyntheticJoin, StreamedJoinAndIndicesMatchTheJoin) {
  const auto features = OpenH5Features(dir_ / "features.h5");
  const Observations joined = JoinObservations(reconstruction_, *features);
  const Observations indices = ObservationIndices(reconstruction_);
  EXPECT_EQ(indices.image_ids, joined.image_ids);
  EXPECT_EQ(indices.keypoint_indices, joined.keypoint_indices);
  EXPECT_EQ(indices.point3D_ids, joined.point3D_ids);
  EXPECT_EQ(indices.descriptors.size(), 0);
  std::vector<std::string> images;
  DescriptorMatrix streamed(0, joined.Dimension());
  const int64_t dimension = ForEachJoinedImage(
      reconstruction_, *features, {},
      [&](const Image& image, const ImageFeatures& image_features,
          const std::vector<point2D_t>& keypoint_rows) {
        images.push_back(image.name);
        const Eigen::Index begin = streamed.rows();
        streamed.conservativeResize(begin + static_cast<Eigen::Index>(keypoint_rows.size()),
                                    Eigen::NoChange);
        for (size_t k = 0; k < keypoint_rows.size(); ++k) {
          streamed.row(begin + static_cast<Eigen::Index>(k)) =
              image_features.descriptors.row(keypoint_rows[k]);
        }
      });
  EXPECT_EQ(dimension, 16);
  EXPECT_THAT(images, ::testing::ElementsAre("sub/b.jpg", "a.jpg"));  // image ids 2, 7
  EXPECT_EQ(streamed, joined.descriptors);
  // The streamed join checks what the join checks.
  reconstruction_.images[7].points2D[19].xy.x() += 0.01;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                ForEachJoinedImage(
                    reconstruction_, *features, {},
                    [](const Image&, const ImageFeatures&, const std::vector<point2D_t>&) {});
              }),
              HasSubstr("image 'a.jpg' (id 7), 2D point 19 (3D point 102)"));
}

TEST_F(SyntheticJoin, KeypointFartherThanTheToleranceIsReported) {
  reconstruction_.images[7].points2D[19].xy.x() += 0.01;
  const auto features = OpenH5Features(dir_ / "features.h5");
  const std::string message =
      testing::InvalidArgumentMessage([&] { JoinObservations(reconstruction_, *features); });
  EXPECT_THAT(message, HasSubstr("image 'a.jpg' (id 7), 2D point 19 (3D point 102)"));
  EXPECT_THAT(message, HasSubstr("max_keypoint_mismatch_px is 0.001"));

  JoinOptions loose;
  loose.max_keypoint_mismatch_px = 0.02;
  EXPECT_EQ(JoinObservations(reconstruction_, *features, loose).size(), 5u);
}

TEST_F(SyntheticJoin, PointIndexBeyondTheKeypointsIsReported) {
  reconstruction_.images[2].points2D.resize(14);
  reconstruction_.images[2].points2D[13].point3D_id = 104;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                JoinObservations(reconstruction_, *OpenH5Features(dir_ / "features.h5"));
              }),
              HasSubstr("image 'sub/b.jpg' (id 2), 2D point 13 (3D point 104): only 12 keypoints"));
}

TEST_F(SyntheticJoin, ImageWithoutFeaturesIsReported) {
  reconstruction_.images[9] = ImageOn(9, "c.jpg", features_a_, {{0, 100}});
  const std::string message = testing::InvalidArgumentMessage(
      [&] { JoinObservations(reconstruction_, *OpenH5Features(dir_ / "features.h5")); });
  EXPECT_THAT(message, HasSubstr((dir_ / "features.h5").string()));
  EXPECT_THAT(message, HasSubstr("image 'c.jpg' (id 9) of the reconstruction has no features"));
}

TEST_F(SyntheticJoin, DescriptorDimensionMismatchNamesBothImages) {
  std::mt19937 random(22);
  const ImageFeatures narrow = RandomFeatures(20, 8, &random);
  reconstruction_.images[7] = ImageOn(7, "a.jpg", narrow, {{3, 100}});
  H5FeatureWriter writer(dir_ / "mixed.h5", H5FloatPrecision::kFloat16);
  writer.Write("a.jpg", narrow, 640, 640);
  writer.Write("sub/b.jpg", features_b_, 640, 640);
  writer.Close();

  JoinOptions options;
  options.max_keypoint_mismatch_px = 0.0;  // keypoints stay float32 in a float16 file
  const std::string message = testing::InvalidArgumentMessage(
      [&] { JoinObservations(reconstruction_, *OpenH5Features(dir_ / "mixed.h5"), options); });
  EXPECT_THAT(message, HasSubstr("descriptor dimension 8 of image 'a.jpg' differs from 16 of image "
                                 "'sub/b.jpg'"));
}

TEST(JoinOptions, CheckRejectsNegativeAndNonFiniteTolerances) {
  JoinOptions options;
  EXPECT_NO_THROW(options.Check());
  for (const double bad :
       {-1e-3, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    options.max_keypoint_mismatch_px = bad;
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { options.Check(); }),
                HasSubstr("max_keypoint_mismatch_px"));
  }
}

TEST(OpenFeatureReader, DispatchesOnTheExtension) {
  testing::TempDir dir;
  std::mt19937 random(1);
  for (const char* name : {"features.h5", "FEATURES.HDF5"}) {
    H5FeatureWriter writer(dir / name, H5FloatPrecision::kFloat32);
    writer.Write("x.jpg", RandomFeatures(3, 4, &random), 640, 480);
    writer.Close();
    EXPECT_THAT(OpenFeatureReader(dir / name)->ImageNames(), ::testing::ElementsAre("x.jpg"));
  }

  // An hloc file renamed .db goes to the database reader, which refuses it.
  std::filesystem::copy_file(dir / "features.h5", dir / "features.db");
  const std::string message =
      testing::InvalidArgumentMessage([&] { OpenFeatureReader(dir / "features.db"); });
  EXPECT_THAT(message, HasSubstr((dir / "features.db").string()));
  EXPECT_THAT(message, HasSubstr("not an SQLite database"));
}

TEST(OpenFeatureReader, UnknownExtensionListsTheAcceptedOnes) {
  for (const char* name : {"features.txt", "features"}) {
    const std::string message = testing::InvalidArgumentMessage([&] { OpenFeatureReader(name); });
    EXPECT_THAT(message, HasSubstr(name));
    EXPECT_THAT(message, HasSubstr(".db"));
    EXPECT_THAT(message, HasSubstr(".h5"));
    EXPECT_THAT(message, HasSubstr(".hdf5"));
  }
}

// Joins a real model with its database and checks every 2D point, not only the observed ones,
// against its keypoint.
void ExpectModelJoinsDatabase(const std::filesystem::path& model_dir,
                              const std::filesystem::path& database, double tolerance_px,
                              size_t expected_observations, int64_t expected_keypoints) {
  const Reconstruction reconstruction = ReadColmapModel(model_dir);
  const auto features = OpenFeatureReader(database);
  double worst_px = 0;
  for (const auto& [image_id, image] : reconstruction.images) {
    const ImageFeatures image_features = features->Read(image.name);
    if (expected_keypoints > 0) {
      EXPECT_EQ(image_features.NumKeypoints(), expected_keypoints) << image.name;
    }
    ASSERT_EQ(static_cast<int64_t>(image.points2D.size()), image_features.NumKeypoints())
        << image.name;
    for (size_t i = 0; i < image.points2D.size(); ++i) {
      const Eigen::Vector2d keypoint = image_features.keypoints.row(i).transpose().cast<double>();
      worst_px = std::max(worst_px, (keypoint - image.points2D[i].xy).norm());
    }
  }
  EXPECT_LE(worst_px, tolerance_px);

  JoinOptions options;
  options.max_keypoint_mismatch_px = tolerance_px;
  const Observations observations = JoinObservations(reconstruction, *features, options);
  EXPECT_EQ(observations.size(), expected_observations);
  EXPECT_EQ(observations.size(), reconstruction.NumObservations());
  EXPECT_EQ(observations.Dimension(), 128);
  ASSERT_EQ(observations.descriptors.rows(), static_cast<int64_t>(observations.size()));
  for (size_t row = 0; row < observations.size(); row += 997) {
    const Image& image = reconstruction.images.at(observations.image_ids[row]);
    EXPECT_EQ(image.points2D[observations.keypoint_indices[row]].point3D_id,
              observations.point3D_ids[row]);
    EXPECT_EQ(observations.descriptors.row(row),
              features->Read(image.name).descriptors.row(observations.keypoint_indices[row]));
  }
}

TEST(JoinObservationsRealData, Fountain) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  ExpectModelJoinsDatabase(data / "map", data / "database.db", 1e-3, 7828, 2048);
}

TEST(JoinObservationsRealData, Lund) {
  HSCLOC_REQUIRE_REAL_DATA(data, "lund");
  ExpectModelJoinsDatabase(data / "map", data / "database.db", 1e-3, 1703, 2048);
}

TEST(JoinObservationsRealData, MaupertuisTextModel) {
  HSCLOC_REQUIRE_REAL_DATA(data, "maupertuis");
  // The text model keeps 6 significant digits: its README measures |dx|, |dy| <= 0.005 px
  // against the database's float32 keypoints, so up to 0.0071 px as a distance (0.0069 is
  // reached). Binary models store the keypoints' doubles and agree exactly.
  ExpectModelJoinsDatabase(data / "map_txt", data / "database.db", 0.01, 3355, 0);
}

}  // namespace
}  // namespace hscloc
