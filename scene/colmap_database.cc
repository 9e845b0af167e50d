#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <set>

#include "scene/feature_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

// The tables and columns read; a database without them is not a COLMAP feature database.
constexpr const char* kRequiredTables[] = {"images", "keypoints", "descriptors"};

struct StatementDeleter {
  void operator()(sqlite3_stmt* statement) const { sqlite3_finalize(statement); }
};
using Statement = std::unique_ptr<sqlite3_stmt, StatementDeleter>;

struct ConnectionDeleter {
  void operator()(sqlite3* db) const { sqlite3_close_v2(db); }
};
using Connection = std::unique_ptr<sqlite3, ConnectionDeleter>;

// One row of the keypoints or descriptors table, as stored.
struct MatrixBlob {
  int64_t rows = 0;
  int64_t cols = 0;
  std::vector<uint8_t> data;
};

class ColmapDatabaseFeatures : public FeatureReader {
 public:
  explicit ColmapDatabaseFeatures(const std::filesystem::path& path) : path_(path) {
    if (!std::filesystem::is_regular_file(path)) {
      ThrowInvalidArgument("COLMAP database {} does not exist or is not a file", path.string());
    }
    sqlite3* raw = nullptr;
    // FULLMUTEX: Read() is const and may be called from several threads on one connection.
    const int rc =
        sqlite3_open_v2(path.c_str(), &raw, SQLITE_OPEN_READONLY | SQLITE_OPEN_FULLMUTEX, nullptr);
    db_.reset(raw);
    if (rc != SQLITE_OK) {
      ThrowInvalidArgument("cannot open COLMAP database {}: {}", path.string(),
                           raw ? sqlite3_errmsg(raw) : sqlite3_errstr(rc));
    }
    CheckTables();
    LoadImages();
  }

  std::vector<std::string> ImageNames() const override {
    std::vector<std::string> names;
    for (const auto& [name, image_id] : image_ids_) {
      if (with_keypoints_.count(image_id) > 0) names.push_back(name);
    }
    return names;
  }

  bool HasImage(const std::string& image_name) const override {
    const auto it = image_ids_.find(image_name);
    return it != image_ids_.end() && with_keypoints_.count(it->second) > 0;
  }

  ImageFeatures Read(const std::string& image_name) const override {
    const auto it = image_ids_.find(image_name);
    if (it == image_ids_.end()) {
      ThrowInvalidArgument("COLMAP database {}: no image named '{}'", path_.string(), image_name);
    }
    const int64_t image_id = it->second;
    const MatrixBlob keypoint_blob = ReadBlob("keypoints", image_id, image_name, sizeof(float));
    const MatrixBlob descriptor_blob = ReadBlob("descriptors", image_id, image_name, 1);
    const auto where = [&](const char* table) {
      return fmt::format("COLMAP database {}, image '{}' (id {}), table {}", path_.string(),
                         image_name, image_id, table);
    };
    if (keypoint_blob.cols != 2 && keypoint_blob.cols != 4 && keypoint_blob.cols != 6) {
      ThrowInvalidArgument("{}: {} columns, expected 2, 4 or 6", where("keypoints"),
                           keypoint_blob.cols);
    }
    if (descriptor_blob.rows != keypoint_blob.rows) {
      ThrowInvalidArgument("{}: {} descriptor rows for {} keypoints", where("descriptors"),
                           descriptor_blob.rows, keypoint_blob.rows);
    }

    ImageFeatures features;
    const int64_t num_keypoints = keypoint_blob.rows;
    features.keypoints.resize(num_keypoints, 2);
    std::vector<float> row(keypoint_blob.cols);
    for (int64_t i = 0; i < num_keypoints; ++i) {
      std::memcpy(row.data(), keypoint_blob.data.data() + i * keypoint_blob.cols * sizeof(float),
                  row.size() * sizeof(float));
      if (!std::isfinite(row[0]) || !std::isfinite(row[1])) {
        ThrowInvalidArgument("{}: keypoint {} is not finite ({}, {})", where("keypoints"), i,
                             row[0], row[1]);
      }
      features.keypoints(i, 0) = row[0];
      features.keypoints(i, 1) = row[1];
    }
    features.descriptors.resize(num_keypoints, descriptor_blob.cols);
    std::transform(descriptor_blob.data.begin(), descriptor_blob.data.end(),
                   features.descriptors.data(), [](uint8_t value) { return float(value); });
    return features;
  }

  const std::filesystem::path& path() const override { return path_; }

 private:
  Statement Prepare(const std::string& sql, const std::string& context) const {
    sqlite3_stmt* raw = nullptr;
    if (sqlite3_prepare_v2(db_.get(), sql.c_str(), -1, &raw, nullptr) != SQLITE_OK) {
      sqlite3_finalize(raw);
      ThrowInvalidArgument("COLMAP database {}: {}: {}", path_.string(), context,
                           sqlite3_errmsg(db_.get()));
    }
    return Statement(raw);
  }

  void CheckTables() const {
    // The first statement is where SQLite reads the header: a non-database file fails here.
    Statement statement =
        Prepare("SELECT name FROM sqlite_master WHERE type = 'table'", "not an SQLite database");
    std::set<std::string> tables;
    int rc;
    while ((rc = sqlite3_step(statement.get())) == SQLITE_ROW) {
      tables.insert(reinterpret_cast<const char*>(sqlite3_column_text(statement.get(), 0)));
    }
    if (rc != SQLITE_DONE) {
      ThrowInvalidArgument("COLMAP database {}: not an SQLite database: {}", path_.string(),
                           sqlite3_errmsg(db_.get()));
    }
    for (const char* table : kRequiredTables) {
      if (tables.count(table) == 0) {
        ThrowInvalidArgument("{} is not a COLMAP database: it has no table '{}'", path_.string(),
                             table);
      }
    }
  }

  void LoadImages() {
    Statement images = Prepare("SELECT image_id, name FROM images", "reading table images");
    int rc;
    while ((rc = sqlite3_step(images.get())) == SQLITE_ROW) {
      const int64_t image_id = sqlite3_column_int64(images.get(), 0);
      const auto* name = reinterpret_cast<const char*>(sqlite3_column_text(images.get(), 1));
      if (name == nullptr) {
        ThrowInvalidArgument("COLMAP database {}, table images: image id {} has no name",
                             path_.string(), image_id);
      }
      image_ids_.emplace(name, image_id);
    }
    StepFailed(rc, "reading table images");
    Statement keypoints = Prepare("SELECT image_id FROM keypoints", "reading table keypoints");
    while ((rc = sqlite3_step(keypoints.get())) == SQLITE_ROW) {
      with_keypoints_.insert(sqlite3_column_int64(keypoints.get(), 0));
    }
    StepFailed(rc, "reading table keypoints");
  }

  void StepFailed(int rc, const std::string& context) const {
    if (rc != SQLITE_DONE) {
      ThrowInvalidArgument("COLMAP database {}: {}: {}", path_.string(), context,
                           sqlite3_errmsg(db_.get()));
    }
  }

  // Reads one (rows, cols, data) record and checks that the blob holds rows * cols elements.
  MatrixBlob ReadBlob(const char* table, int64_t image_id, const std::string& image_name,
                      size_t element_size) const {
    const std::string context =
        fmt::format("image '{}' (id {}), table {}", image_name, image_id, table);
    Statement statement =
        Prepare(fmt::format("SELECT rows, cols, data FROM {} WHERE image_id = ?", table), context);
    sqlite3_bind_int64(statement.get(), 1, image_id);
    const int rc = sqlite3_step(statement.get());
    if (rc == SQLITE_DONE) {
      ThrowInvalidArgument("COLMAP database {}: image '{}' (id {}) has no row in table {}",
                           path_.string(), image_name, image_id, table);
    }
    if (rc != SQLITE_ROW) StepFailed(rc, context);

    MatrixBlob blob;
    blob.rows = sqlite3_column_int64(statement.get(), 0);
    blob.cols = sqlite3_column_int64(statement.get(), 1);
    const auto* data = static_cast<const uint8_t*>(sqlite3_column_blob(statement.get(), 2));
    const int64_t num_bytes = sqlite3_column_bytes(statement.get(), 2);
    // Bounds before the product, so that a corrupt header cannot overflow it.
    constexpr int64_t kMaxDimension = int64_t{1} << 31;
    if (blob.rows < 0 || blob.cols < 0 || blob.rows >= kMaxDimension ||
        blob.cols >= kMaxDimension) {
      ThrowInvalidArgument("COLMAP database {}: {}: invalid shape {} x {}", path_.string(), context,
                           blob.rows, blob.cols);
    }
    const int64_t expected_bytes = blob.rows * blob.cols * static_cast<int64_t>(element_size);
    if (num_bytes != expected_bytes) {
      ThrowInvalidArgument(
          "COLMAP database {}: {}: blob of {} bytes, expected {} ({} rows x {} cols x {} bytes)",
          path_.string(), context, num_bytes, expected_bytes, blob.rows, blob.cols, element_size);
    }
    if (num_bytes > 0) blob.data.assign(data, data + num_bytes);
    return blob;
  }

  std::filesystem::path path_;
  Connection db_;
  std::map<std::string, int64_t> image_ids_;  // sorted, so ImageNames() needs no sort
  std::set<int64_t> with_keypoints_;
};

}  // namespace

std::unique_ptr<FeatureReader> OpenColmapDatabaseFeatures(const std::filesystem::path& path) {
  return std::make_unique<ColmapDatabaseFeatures>(path);
}

}  // namespace hscloc
