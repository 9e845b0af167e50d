#include "scene/colmap_database_writer.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cstring>

#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

// Reads a written database with the SQLite C API, independently of the writer.
class DatabaseReader {
 public:
  explicit DatabaseReader(const fs::path& path) {
    EXPECT_EQ(sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  }
  ~DatabaseReader() { sqlite3_close(db_); }

  // Every row of the query, its columns as text joined by '|' (blobs as their byte count).
  std::vector<std::string> Rows(const std::string& sql) {
    sqlite3_stmt* statement = nullptr;
    EXPECT_EQ(sqlite3_prepare_v2(db_, sql.c_str(), -1, &statement, nullptr), SQLITE_OK) << sql;
    std::vector<std::string> rows;
    while (sqlite3_step(statement) == SQLITE_ROW) {
      std::string row;
      for (int i = 0; i < sqlite3_column_count(statement); ++i) {
        if (i > 0) row += '|';
        if (sqlite3_column_type(statement, i) == SQLITE_BLOB) {
          row += std::to_string(sqlite3_column_bytes(statement, i)) + " bytes";
        } else if (const auto* text = sqlite3_column_text(statement, i)) {
          row += reinterpret_cast<const char*>(text);
        }
      }
      rows.push_back(row);
    }
    sqlite3_finalize(statement);
    return rows;
  }

  template <typename T>
  std::vector<T> Blob(const std::string& sql) {
    sqlite3_stmt* statement = nullptr;
    EXPECT_EQ(sqlite3_prepare_v2(db_, sql.c_str(), -1, &statement, nullptr), SQLITE_OK) << sql;
    EXPECT_EQ(sqlite3_step(statement), SQLITE_ROW) << sql;
    std::vector<T> values(sqlite3_column_bytes(statement, 0) / sizeof(T));
    std::memcpy(values.data(), sqlite3_column_blob(statement, 0), values.size() * sizeof(T));
    sqlite3_finalize(statement);
    return values;
  }

 private:
  sqlite3* db_ = nullptr;
};

Camera TestCamera(camera_t camera_id) {
  return Camera::FromModelName(camera_id, "SIMPLE_RADIAL", 1024, 768, {995, 512, 384, 0.13});
}

TEST(ColmapDatabaseWriter, SchemaIsColmapsOwn) {
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir temp;
  ASSERT_EQ(testing::RunCommand(fmt::format("{} database_creator --database_path {}", colmap,
                                            (temp / "colmap.db").string()),
                                (temp / "colmap.log").string()),
            0);
  ColmapDatabaseWriter(temp / "ours.db").Close();
  const std::string schema = "SELECT type, name, tbl_name, sql FROM sqlite_master ORDER BY name";
  const std::vector<std::string> expected = DatabaseReader(temp / "colmap.db").Rows(schema);
  EXPECT_EQ(DatabaseReader(temp / "ours.db").Rows(schema), expected);
  EXPECT_EQ(expected.size(), 9u);
  EXPECT_EQ(DatabaseReader(temp / "ours.db").Rows("PRAGMA user_version"),
            DatabaseReader(temp / "colmap.db").Rows("PRAGMA user_version"));
}

class ColmapDatabaseWriterTest : public ::testing::Test {
 protected:
  testing::TempDir temp_;
  const fs::path path_ = temp_ / "database.db";
};

TEST_F(ColmapDatabaseWriterTest, WritesRecordsInColmapsLayout) {
  {
    ColmapDatabaseWriter writer(path_);
    writer.WriteCamera(TestCamera(3));
    writer.WriteImage(7, "a.jpg", 3);
    writer.WriteImage(2, "dir/b.jpg", 3);
    KeypointMatrix keypoints(2, 2);
    keypoints << 0.5f, 1.25f, 1023.5f, 767.5f;
    writer.WriteKeypoints(7, keypoints);
    // Given as (7, 2): stored under (2, 7) with the columns swapped.
    writer.WriteMatches(7, 2, {{0, 5}, {1, 9}});
    const Rigid3d cam2_from_cam7(
        Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY())),
        Eigen::Vector3d(1, 0, 0));
    writer.WriteTwoViewGeometry(7, 2, {{1, 9}}, cam2_from_cam7);
    writer.Close();
  }
  DatabaseReader db(path_);
  EXPECT_THAT(db.Rows("SELECT camera_id, model, width, height, params, prior_focal_length "
                      "FROM cameras"),
              ElementsAre("3|2|1024|768|32 bytes|1"));
  EXPECT_THAT(db.Blob<double>("SELECT params FROM cameras"), ElementsAre(995, 512, 384, 0.13));
  EXPECT_THAT(db.Rows("SELECT image_id, name, camera_id FROM images ORDER BY image_id"),
              ElementsAre("2|dir/b.jpg|3", "7|a.jpg|3"));
  EXPECT_THAT(db.Rows("SELECT image_id, rows, cols FROM keypoints"), ElementsAre("7|2|2"));
  EXPECT_THAT(db.Blob<float>("SELECT data FROM keypoints"), ElementsAre(0.5, 1.25, 1023.5, 767.5));

  const int64_t pair_id = 2 * int64_t{2147483647} + 7;
  EXPECT_EQ(ColmapPairId(7, 2), pair_id);
  EXPECT_THAT(db.Rows("SELECT pair_id, rows, cols FROM matches"),
              ElementsAre(fmt::format("{}|2|2", pair_id)));
  EXPECT_THAT(db.Blob<uint32_t>("SELECT data FROM matches"), ElementsAre(5, 0, 9, 1));
  EXPECT_THAT(db.Rows("SELECT pair_id, rows, cols, config FROM two_view_geometries"),
              ElementsAre(fmt::format("{}|1|2|2", pair_id)));
  EXPECT_THAT(db.Blob<uint32_t>("SELECT data FROM two_view_geometries"), ElementsAre(9, 1));
  // The stored relative pose is cam7_from_cam2, and E = [t]x R satisfies x7^T E x2 = 0 for a
  // point seen by both cameras.
  const std::vector<double> qvec = db.Blob<double>("SELECT qvec FROM two_view_geometries");
  const std::vector<double> tvec = db.Blob<double>("SELECT tvec FROM two_view_geometries");
  const std::vector<double> e = db.Blob<double>("SELECT E FROM two_view_geometries");
  ASSERT_EQ(qvec.size(), 4u);
  ASSERT_EQ(tvec.size(), 3u);
  ASSERT_EQ(e.size(), 9u);
  const Rigid3d cam7_from_cam2(Eigen::Quaterniond(qvec[0], qvec[1], qvec[2], qvec[3]),
                               Eigen::Vector3d(tvec[0], tvec[1], tvec[2]));
  const Eigen::Vector3d point_in_cam2(0.2, -0.4, 5);
  const Eigen::Vector3d point_in_cam7 = cam7_from_cam2 * point_in_cam2;
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> essential(e.data());
  EXPECT_NEAR(point_in_cam7.normalized().dot(essential * point_in_cam2.normalized()), 0, 1e-12);
  // Camera 7's centre, (1, 0, 0) in camera 2, is cam7's origin.
  EXPECT_NEAR((cam7_from_cam2 * Eigen::Vector3d(1, 0, 0)).norm(), 0, 1e-12);
}

TEST_F(ColmapDatabaseWriterTest, RefusesWhatColmapWouldRefuse) {
  {
    ColmapDatabaseWriter writer(path_);
    writer.WriteCamera(TestCamera(1));
    writer.WriteImage(1, "a.jpg", 1);
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.WriteImage(2, "b.jpg", 9); }),
                HasSubstr("writing image 2 'b.jpg' (camera 9)"));
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.WriteImage(3, "a.jpg", 1); }),
                HasSubstr("UNIQUE"));
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.WriteMatches(1, 1, {}); }),
                HasSubstr("image 1 with itself"));
    writer.WriteMatches(1, 2, {});
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.WriteMatches(2, 1, {}); }),
                HasSubstr("writing the matches of images 2 and 1"));
  }
  // Not closed: nothing was committed.
  EXPECT_TRUE(DatabaseReader(path_).Rows("SELECT * FROM images").empty());
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ColmapDatabaseWriter writer(path_); }),
              HasSubstr("exists already"));
}

}  // namespace
}  // namespace hscloc
