#include "pipeline/dataset_layout.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "pipeline/dataset_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::MakeHsclocDataset;
using testing::QueryLine;
using testing::Touch;
using testing::WriteModel;

// The layout of Aachen Day-Night v1.1, in miniature.
void MakeAachenDataset(const fs::path& dir) {
  const fs::path images = dir / "images" / "images_upright";
  for (const char* name : {"db/1.jpg", "db/2.jpg", "query/day/d.jpg", "query/night/n.jpg"}) {
    Touch(images / name);
  }
  WriteModel(dir / "3D-models" / "aachen_v_1_1", {"db/1.jpg", "db/2.jpg"});
  Touch(dir / "queries" / "day_time_queries_with_intrinsics.txt", QueryLine("query/day/d.jpg"));
  Touch(dir / "queries" / "night_time_queries_with_intrinsics.txt", QueryLine("query/night/n.jpg"));
}

TEST(DatasetLayoutTest, FindsTheLayoutOfData) {
  testing::TempDir dir;
  MakeHsclocDataset(dir.path());
  const DatasetLayout layout = FindDatasetLayout(dir.path());
  EXPECT_EQ(layout.kind, "hscloc");
  EXPECT_EQ(layout.images_dir, dir / "images");
  EXPECT_EQ(layout.model_dir, dir / "map");
  ASSERT_EQ(layout.query_lists.size(), 1u);
  EXPECT_EQ(layout.query_lists[0].first, "all");
  ASSERT_TRUE(layout.ground_truth.has_value());
  EXPECT_EQ(DatasetPhotos(layout), (std::vector<std::string>{"a.jpg", "b.jpg", "q.jpg"}));
}

TEST(DatasetLayoutTest, FindsTheLayoutOfAachenWithItsConditions) {
  testing::TempDir dir;
  MakeAachenDataset(dir.path());
  const DatasetLayout layout = FindDatasetLayout(dir.path());
  EXPECT_EQ(layout.kind, "aachen");
  EXPECT_EQ(layout.images_dir, dir / "images" / "images_upright");
  EXPECT_EQ(layout.model_dir, dir / "3D-models" / "aachen_v_1_1");
  ASSERT_EQ(layout.query_lists.size(), 2u);
  EXPECT_EQ(layout.query_lists[0].first, "day_time");
  EXPECT_EQ(layout.query_lists[1].first, "night_time");
  EXPECT_FALSE(layout.ground_truth.has_value());
  EXPECT_EQ(
      DatasetPhotos(layout),
      (std::vector<std::string>{"db/1.jpg", "db/2.jpg", "query/day/d.jpg", "query/night/n.jpg"}));
}

TEST(DatasetLayoutTest, AFolderInNeitherLayoutNamesWhatEachLacks) {
  testing::TempDir dir;
  Touch(dir / "images" / "a.jpg");
  const std::string message =
      testing::InvalidArgumentMessage([&] { FindDatasetLayout(dir.path()); });
  EXPECT_THAT(message, HasSubstr((dir / "map").string()));
  EXPECT_THAT(message, HasSubstr((dir / "images" / "images_upright").string()));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { FindDatasetLayout(dir / "absent"); }),
              HasSubstr("does not exist"));
}

TEST(DatasetLayoutTest, AMapFolderWithoutAModelIsNotTheLayoutOfData) {
  testing::TempDir dir;
  MakeHsclocDataset(dir.path());
  fs::remove(dir / "map" / "cameras.txt");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { FindDatasetLayout(dir.path()); }),
              HasSubstr((dir / "map" / "cameras.bin").string()));
}

TEST(DatasetLayoutTest, AQueryNamingAMissingPhotoIsNamed) {
  testing::TempDir dir;
  MakeHsclocDataset(dir.path());
  Touch(dir / "queries_with_intrinsics.txt", QueryLine("q.jpg") + QueryLine("lost.jpg"));
  const DatasetLayout layout = FindDatasetLayout(dir.path());
  const std::string message = testing::InvalidArgumentMessage([&] { DatasetPhotos(layout); });
  EXPECT_THAT(message, HasSubstr("lost.jpg"));
  EXPECT_THAT(message, HasSubstr("queries_with_intrinsics.txt"));
}

TEST(DatasetLayoutTest, AModelWhoseImagesAreNotThePhotosIsRefused) {
  testing::TempDir dir;
  MakeHsclocDataset(dir.path());
  fs::remove(dir / "images" / "b.jpg");
  const DatasetLayout layout = FindDatasetLayout(dir.path());
  const std::string message = testing::InvalidArgumentMessage([&] { DatasetPhotos(layout); });
  EXPECT_THAT(message, HasSubstr("does not match the photos"));
  EXPECT_THAT(message, HasSubstr("b.jpg"));
}

TEST(DatasetLayoutTest, AQueryThatIsAMapImageIsRefused) {
  testing::TempDir dir;
  MakeHsclocDataset(dir.path());
  Touch(dir / "queries_with_intrinsics.txt", QueryLine("q.jpg") + QueryLine("a.jpg"));
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { DatasetPhotos(FindDatasetLayout(dir.path())); }),
      HasSubstr("a.jpg"));
}

}  // namespace
}  // namespace hscloc
