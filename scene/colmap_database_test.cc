#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cstring>
#include <limits>

#include "scene/feature_io.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// A writable copy of a real database, edited with the SQLite C API (independent of the reader).
class DatabaseCopy {
 public:
  DatabaseCopy(const std::filesystem::path& source, const std::filesystem::path& copy)
      : path_(copy) {
    std::filesystem::copy_file(source, copy);
    std::filesystem::permissions(copy, std::filesystem::perms::owner_write,
                                 std::filesystem::perm_options::add);
    EXPECT_EQ(sqlite3_open(copy.c_str(), &db_), SQLITE_OK);
  }
  ~DatabaseCopy() { sqlite3_close(db_); }

  void Execute(const std::string& sql) {
    char* error = nullptr;
    EXPECT_EQ(sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &error), SQLITE_OK)
        << sql << ": " << (error ? error : "");
    sqlite3_free(error);
  }

  std::vector<uint8_t> Blob(const char* table, int image_id) {
    sqlite3_stmt* statement = nullptr;
    sqlite3_prepare_v2(db_,
                       (std::string("SELECT data FROM ") + table + " WHERE image_id = ?").c_str(),
                       -1, &statement, nullptr);
    sqlite3_bind_int(statement, 1, image_id);
    EXPECT_EQ(sqlite3_step(statement), SQLITE_ROW);
    const auto* data = static_cast<const uint8_t*>(sqlite3_column_blob(statement, 0));
    std::vector<uint8_t> blob(data, data + sqlite3_column_bytes(statement, 0));
    sqlite3_finalize(statement);
    return blob;
  }

  void SetBlob(const char* table, int image_id, int64_t rows, const std::vector<uint8_t>& blob) {
    sqlite3_stmt* statement = nullptr;
    sqlite3_prepare_v2(
        db_,
        (std::string("UPDATE ") + table + " SET rows = ?, data = ? WHERE image_id = ?").c_str(), -1,
        &statement, nullptr);
    sqlite3_bind_int64(statement, 1, rows);
    sqlite3_bind_blob(statement, 2, blob.data(), static_cast<int>(blob.size()), SQLITE_TRANSIENT);
    sqlite3_bind_int(statement, 3, image_id);
    EXPECT_EQ(sqlite3_step(statement), SQLITE_DONE);
    sqlite3_finalize(statement);
  }

  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
  sqlite3* db_ = nullptr;
};

TEST(ColmapDatabase, ReadsFountainKeypointsAndDescriptorsAsStored) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  const auto reader = OpenColmapDatabaseFeatures(data / "database.db");
  const std::vector<std::string> names = reader->ImageNames();
  ASSERT_EQ(names.size(), 11u);
  EXPECT_TRUE(std::is_sorted(names.begin(), names.end()));
  EXPECT_EQ(names.front(), "0000.jpg");
  for (const std::string& name : names) {
    SCOPED_TRACE(name);
    const ImageFeatures features = reader->Read(name);
    EXPECT_EQ(features.NumKeypoints(), 2048);
    EXPECT_EQ(features.Dimension(), 128);
    EXPECT_EQ(features.scores.size(), 0);
    EXPECT_GE(features.keypoints.minCoeff(), 0.f);
    EXPECT_LE(features.keypoints.col(0).maxCoeff(), 1536.f);
    EXPECT_LE(features.keypoints.col(1).maxCoeff(), 1024.f);
    // uint8 values cast, not rescaled: integers up to 255, and SIFT's L2 norm near 512.
    EXPECT_TRUE((features.descriptors.array() == features.descriptors.array().round()).all());
    EXPECT_LE(features.descriptors.maxCoeff(), 255.f);
    EXPECT_NEAR(features.descriptors.row(0).norm(), 512.f, 30.f);
    // A database keeps the photo's size on the camera only.
    EXPECT_EQ(reader->ImageSize(name), std::nullopt);
  }
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->ImageSize("absent.jpg"); }),
              ::testing::HasSubstr("absent.jpg"));

  // The first keypoint of image id 1 against its blob, read independently: no pixel shift.
  testing::TempDir dir;
  DatabaseCopy copy(data / "database.db", dir / "database.db");
  const std::vector<uint8_t> blob = copy.Blob("keypoints", 1);
  float first[6];
  std::memcpy(first, blob.data(), sizeof(first));
  const ImageFeatures features = reader->Read("0000.jpg");
  EXPECT_EQ(features.keypoints(0, 0), first[0]);
  EXPECT_EQ(features.keypoints(0, 1), first[1]);
  EXPECT_EQ(features.descriptors(0, 5), float(copy.Blob("descriptors", 1)[5]));
}

TEST(ColmapDatabase, ReadsLundAndSixColumnMaupertuisKeypoints) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  const auto lund_reader = OpenColmapDatabaseFeatures(lund / "database.db");
  ASSERT_EQ(lund_reader->ImageNames().size(), 29u);
  for (const std::string& name : lund_reader->ImageNames()) {
    EXPECT_EQ(lund_reader->Read(name).NumKeypoints(), 2048) << name;
  }

  HSCLOC_REQUIRE_REAL_DATA(maupertuis, "maupertuis");
  const auto reader = OpenColmapDatabaseFeatures(maupertuis / "database.db");
  EXPECT_THAT(reader->ImageNames(), ::testing::ElementsAre("00.jpg", "01.jpg", "02.jpg", "03.jpg"));
  int64_t total = 0, fewest = std::numeric_limits<int64_t>::max(), most = 0;
  for (const std::string& name : reader->ImageNames()) {
    const ImageFeatures features = reader->Read(name);
    EXPECT_EQ(features.Dimension(), 128);
    EXPECT_LE(features.keypoints.col(0).maxCoeff(), 1919.f);
    EXPECT_LE(features.keypoints.col(1).maxCoeff(), 1079.f);
    total += features.NumKeypoints();
    fewest = std::min(fewest, features.NumKeypoints());
    most = std::max(most, features.NumKeypoints());
  }
  EXPECT_EQ(total, 24010);
  EXPECT_EQ(fewest, 5576);
  EXPECT_EQ(most, 6424);
}

TEST(ColmapDatabase, TruncatedKeypointBlobNamesFileImageAndTable) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  testing::TempDir dir;
  DatabaseCopy copy(data / "database.db", dir / "database.db");
  std::vector<uint8_t> blob = copy.Blob("keypoints", 3);
  blob.resize(blob.size() - 10);
  copy.SetBlob("keypoints", 3, 2048, blob);

  const auto reader = OpenColmapDatabaseFeatures(copy.path());
  const std::string message = testing::InvalidArgumentMessage([&] { reader->Read("0002.jpg"); });
  EXPECT_THAT(message, HasSubstr(copy.path().string()));
  EXPECT_THAT(message, HasSubstr("image '0002.jpg' (id 3), table keypoints"));
  EXPECT_THAT(message, HasSubstr("blob of 49142 bytes, expected 49152"));
  EXPECT_NO_THROW(reader->Read("0001.jpg"));
}

TEST(ColmapDatabase, DescriptorRowsDifferingFromKeypointRowsAreReported) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  testing::TempDir dir;
  DatabaseCopy copy(data / "database.db", dir / "database.db");
  std::vector<uint8_t> blob = copy.Blob("descriptors", 2);
  blob.resize(2047 * 128);  // consistent on its own, one row short of the keypoints
  copy.SetBlob("descriptors", 2, 2047, blob);

  const std::string message = testing::InvalidArgumentMessage(
      [&] { OpenColmapDatabaseFeatures(copy.path())->Read("0001.jpg"); });
  EXPECT_THAT(message, HasSubstr(copy.path().string()));
  EXPECT_THAT(message, HasSubstr("image '0001.jpg'"));
  EXPECT_THAT(message, HasSubstr("2047 descriptor rows for 2048 keypoints"));
}

TEST(ColmapDatabase, NonFiniteKeypointIsReported) {
  HSCLOC_REQUIRE_REAL_DATA(data, "maupertuis");
  testing::TempDir dir;
  DatabaseCopy copy(data / "database.db", dir / "database.db");
  std::vector<uint8_t> blob = copy.Blob("keypoints", 4);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(blob.data() + (7 * 6 + 1) * sizeof(float), &nan, sizeof(nan));  // keypoint 7, y
  copy.SetBlob("keypoints", 4, static_cast<int64_t>(blob.size() / 24), blob);

  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { OpenColmapDatabaseFeatures(copy.path())->Read("03.jpg"); }),
              HasSubstr("image '03.jpg' (id 4), table keypoints: keypoint 7 is not finite"));
}

TEST(ColmapDatabase, MissingImagesAreReported) {
  HSCLOC_REQUIRE_REAL_DATA(data, "fountain-P11");
  testing::TempDir dir;
  DatabaseCopy copy(data / "database.db", dir / "database.db");
  copy.Execute("DELETE FROM keypoints WHERE image_id = 5");

  const auto reader = OpenColmapDatabaseFeatures(copy.path());
  EXPECT_FALSE(reader->HasImage("nowhere.jpg"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->Read("nowhere.jpg"); }),
              HasSubstr("no image named 'nowhere.jpg'"));
  // 0004.jpg is in the images table without keypoints: no features, and said so.
  EXPECT_FALSE(reader->HasImage("0004.jpg"));
  EXPECT_EQ(reader->ImageNames().size(), 10u);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->Read("0004.jpg"); }),
              HasSubstr("image '0004.jpg' (id 5) has no row in table keypoints"));
}

TEST(ColmapDatabase, FilesThatAreNotColmapDatabasesAreReported) {
  testing::TempDir dir;
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { OpenColmapDatabaseFeatures(dir / "absent.db"); }),
      HasSubstr("does not exist"));

  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open((dir / "other.db").c_str(), &db), SQLITE_OK);
  sqlite3_exec(db, "CREATE TABLE images (image_id INTEGER, name TEXT, camera_id INTEGER)", nullptr,
               nullptr, nullptr);
  sqlite3_close(db);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { OpenColmapDatabaseFeatures(dir / "other.db"); }),
      HasSubstr("has no table 'keypoints'"));
}

}  // namespace
}  // namespace hscloc
