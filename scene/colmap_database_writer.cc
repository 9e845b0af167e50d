#include "scene/colmap_database_writer.h"

#include <sqlite3.h>

#include <array>

#include "geometry/essential_matrix.h"
#include "util/check.h"

namespace hscloc {
namespace {

// COLMAP 3.8's CREATE statements, as sqlite_master holds them after `colmap database_creator`, in
// its order; the pragma marks the schema version COLMAP 3.8 writes.
constexpr const char* kSchema[] = {
    "CREATE TABLE cameras   (camera_id            INTEGER  PRIMARY KEY AUTOINCREMENT  NOT NULL,"
    "    model                INTEGER                             NOT NULL,"
    "    width                INTEGER                             NOT NULL,"
    "    height               INTEGER                             NOT NULL,"
    "    params               BLOB,"
    "    prior_focal_length   INTEGER                             NOT NULL)",
    "CREATE TABLE images   (image_id   INTEGER  PRIMARY KEY AUTOINCREMENT  NOT NULL,"
    "    name       TEXT                                NOT NULL UNIQUE,"
    "    camera_id  INTEGER                             NOT NULL,"
    "    prior_qw   REAL,"
    "    prior_qx   REAL,"
    "    prior_qy   REAL,"
    "    prior_qz   REAL,"
    "    prior_tx   REAL,"
    "    prior_ty   REAL,"
    "    prior_tz   REAL,"
    "CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647),"
    "FOREIGN KEY(camera_id) REFERENCES cameras(camera_id))",
    "CREATE UNIQUE INDEX index_name ON images(name)",
    "CREATE TABLE keypoints   (image_id  INTEGER  PRIMARY KEY  NOT NULL,"
    "    rows      INTEGER               NOT NULL,"
    "    cols      INTEGER               NOT NULL,"
    "    data      BLOB,"
    "FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE)",
    "CREATE TABLE descriptors   (image_id  INTEGER  PRIMARY KEY  NOT NULL,"
    "    rows      INTEGER               NOT NULL,"
    "    cols      INTEGER               NOT NULL,"
    "    data      BLOB,"
    "FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE)",
    "CREATE TABLE matches   (pair_id  INTEGER  PRIMARY KEY  NOT NULL,"
    "    rows     INTEGER               NOT NULL,"
    "    cols     INTEGER               NOT NULL,"
    "    data     BLOB)",
    "CREATE TABLE two_view_geometries   (pair_id  INTEGER  PRIMARY KEY  NOT NULL,"
    "    rows     INTEGER               NOT NULL,"
    "    cols     INTEGER               NOT NULL,"
    "    data     BLOB,"
    "    config   INTEGER               NOT NULL,"
    "    F        BLOB,"
    "    E        BLOB,"
    "    H        BLOB,"
    "    qvec     BLOB,"
    "    tvec     BLOB)",
    "PRAGMA user_version = 3800",
};

struct StatementDeleter {
  void operator()(sqlite3_stmt* statement) const { sqlite3_finalize(statement); }
};
using Statement = std::unique_ptr<sqlite3_stmt, StatementDeleter>;

// Matches as COLMAP stores them: the pair in increasing id order, uint32 columns.
std::vector<uint32_t> MatchBlob(image_t image_id1, image_t image_id2,
                                const std::vector<FeatureMatch>& matches) {
  const bool swap = image_id1 > image_id2;
  std::vector<uint32_t> blob;
  blob.reserve(2 * matches.size());
  for (const FeatureMatch& match : matches) {
    blob.push_back(swap ? match.point2D_idx2 : match.point2D_idx1);
    blob.push_back(swap ? match.point2D_idx1 : match.point2D_idx2);
  }
  return blob;
}

// Row-major, as COLMAP writes Eigen matrices into blobs.
std::array<double, 9> RowMajor(const Eigen::Matrix3d& matrix) {
  std::array<double, 9> values;
  Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(values.data()) = matrix;
  return values;
}

}  // namespace

int64_t ColmapPairId(image_t image_id1, image_t image_id2) {
  if (image_id1 > image_id2) std::swap(image_id1, image_id2);
  return int64_t{image_id1} * kColmapMaxNumImages + image_id2;
}

struct ColmapDatabaseWriter::Impl {
  std::filesystem::path path;
  sqlite3* db = nullptr;
  bool in_transaction = false;

  [[noreturn]] void Fail(const std::string& context) const {
    ThrowInvalidArgument("COLMAP database {}: {}: {}", path.string(), context, sqlite3_errmsg(db));
  }

  void Execute(const std::string& sql) const {
    if (sqlite3_exec(db, sql.c_str(), nullptr, nullptr, nullptr) != SQLITE_OK) Fail(sql);
  }

  Statement Prepare(const char* sql) const {
    sqlite3_stmt* raw = nullptr;
    if (sqlite3_prepare_v2(db, sql, -1, &raw, nullptr) != SQLITE_OK) {
      sqlite3_finalize(raw);
      Fail(sql);
    }
    return Statement(raw);
  }

  void Step(const Statement& statement, const std::string& context) const {
    if (sqlite3_step(statement.get()) != SQLITE_DONE) Fail(context);
  }

  template <typename T>
  void BindBlob(const Statement& statement, int index, const T* data, size_t count) const {
    sqlite3_bind_blob64(statement.get(), index, data, count * sizeof(T), SQLITE_TRANSIENT);
  }

  // The matches or two_view_geometries row of a pair, its first four columns.
  Statement PairRow(const char* sql, image_t image_id1, image_t image_id2,
                    const std::vector<uint32_t>& blob) const {
    if (image_id1 == image_id2) {
      ThrowInvalidArgument("COLMAP database {}: a pair of image {} with itself", path.string(),
                           image_id1);
    }
    Statement statement = Prepare(sql);
    sqlite3_bind_int64(statement.get(), 1, ColmapPairId(image_id1, image_id2));
    sqlite3_bind_int64(statement.get(), 2, static_cast<int64_t>(blob.size() / 2));
    sqlite3_bind_int64(statement.get(), 3, 2);
    BindBlob(statement, 4, blob.data(), blob.size());
    return statement;
  }
};

ColmapDatabaseWriter::ColmapDatabaseWriter(const std::filesystem::path& path)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  if (std::filesystem::exists(path)) {
    ThrowInvalidArgument("COLMAP database {} exists already; remove it or choose another path",
                         path.string());
  }
  const int rc = sqlite3_open_v2(path.c_str(), &impl_->db,
                                 SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr);
  if (rc != SQLITE_OK) {
    ThrowInvalidArgument("cannot create COLMAP database {}: {}", path.string(),
                         impl_->db ? sqlite3_errmsg(impl_->db) : sqlite3_errstr(rc));
  }
  // COLMAP opens its databases with foreign keys on; checking them here catches an image whose
  // camera was not written, as COLMAP would.
  impl_->Execute("PRAGMA foreign_keys = ON");
  for (const char* statement : kSchema) impl_->Execute(statement);
  impl_->Execute("BEGIN TRANSACTION");
  impl_->in_transaction = true;
}

ColmapDatabaseWriter::~ColmapDatabaseWriter() {
  if (impl_->in_transaction) sqlite3_exec(impl_->db, "ROLLBACK", nullptr, nullptr, nullptr);
  sqlite3_close_v2(impl_->db);
}

void ColmapDatabaseWriter::WriteCamera(const Camera& camera) {
  camera.Check();
  const Statement statement = impl_->Prepare(
      "INSERT INTO cameras(camera_id, model, width, height, params, prior_focal_length) "
      "VALUES(?, ?, ?, ?, ?, 1)");
  sqlite3_bind_int64(statement.get(), 1, camera.camera_id);
  sqlite3_bind_int64(statement.get(), 2, static_cast<int>(camera.model_id));
  sqlite3_bind_int64(statement.get(), 3, static_cast<int64_t>(camera.width));
  sqlite3_bind_int64(statement.get(), 4, static_cast<int64_t>(camera.height));
  impl_->BindBlob(statement, 5, camera.params.data(), camera.params.size());
  impl_->Step(statement, fmt::format("writing camera {}", camera.camera_id));
}

void ColmapDatabaseWriter::WriteImage(image_t image_id, const std::string& name,
                                      camera_t camera_id) {
  if (image_id >= kColmapMaxNumImages) {
    ThrowInvalidArgument("COLMAP database {}: image id {} of '{}' is not below {}",
                         impl_->path.string(), image_id, name, kColmapMaxNumImages);
  }
  const Statement statement =
      impl_->Prepare("INSERT INTO images(image_id, name, camera_id) VALUES(?, ?, ?)");
  sqlite3_bind_int64(statement.get(), 1, image_id);
  sqlite3_bind_text(statement.get(), 2, name.c_str(), static_cast<int>(name.size()),
                    SQLITE_TRANSIENT);
  sqlite3_bind_int64(statement.get(), 3, camera_id);
  impl_->Step(statement,
              fmt::format("writing image {} '{}' (camera {})", image_id, name, camera_id));
}

void ColmapDatabaseWriter::WriteKeypoints(image_t image_id, const KeypointMatrix& keypoints) {
  const Statement statement =
      impl_->Prepare("INSERT INTO keypoints(image_id, rows, cols, data) VALUES(?, ?, 2, ?)");
  sqlite3_bind_int64(statement.get(), 1, image_id);
  sqlite3_bind_int64(statement.get(), 2, keypoints.rows());
  impl_->BindBlob(statement, 3, keypoints.data(), keypoints.size());
  impl_->Step(statement, fmt::format("writing the keypoints of image {}", image_id));
}

void ColmapDatabaseWriter::WriteMatches(image_t image_id1, image_t image_id2,
                                        const std::vector<FeatureMatch>& matches) {
  const Statement statement =
      impl_->PairRow("INSERT INTO matches(pair_id, rows, cols, data) VALUES(?, ?, ?, ?)", image_id1,
                     image_id2, MatchBlob(image_id1, image_id2, matches));
  impl_->Step(statement,
              fmt::format("writing the matches of images {} and {}", image_id1, image_id2));
}

void ColmapDatabaseWriter::WriteTwoViewGeometry(image_t image_id1, image_t image_id2,
                                                const std::vector<FeatureMatch>& inlier_matches,
                                                const Rigid3d& cam2_from_cam1,
                                                TwoViewConfiguration configuration) {
  const Statement statement = impl_->PairRow(
      "INSERT INTO two_view_geometries(pair_id, rows, cols, data, config, F, E, H, qvec, tvec) "
      "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
      image_id1, image_id2, MatchBlob(image_id1, image_id2, inlier_matches));
  // The stored pair runs from the smaller id to the larger one.
  const Rigid3d second_from_first =
      image_id1 < image_id2 ? cam2_from_cam1 : cam2_from_cam1.Inverse();
  const std::array<double, 9> zero{};
  const std::array<double, 9> essential = RowMajor(EssentialMatrix(second_from_first));
  const Eigen::Quaterniond& q = second_from_first.rotation;
  const std::array<double, 4> qvec = {q.w(), q.x(), q.y(), q.z()};
  const Eigen::Vector3d& tvec = second_from_first.translation;
  sqlite3_bind_int(statement.get(), 5, static_cast<int>(configuration));
  impl_->BindBlob(statement, 6, zero.data(), zero.size());
  impl_->BindBlob(statement, 7, essential.data(), essential.size());
  impl_->BindBlob(statement, 8, zero.data(), zero.size());
  impl_->BindBlob(statement, 9, qvec.data(), qvec.size());
  impl_->BindBlob(statement, 10, tvec.data(), 3);
  impl_->Step(statement, fmt::format("writing the two-view geometry of images {} and {}", image_id1,
                                     image_id2));
}

void ColmapDatabaseWriter::Close() {
  if (!impl_->in_transaction) return;
  impl_->Execute("COMMIT");
  impl_->in_transaction = false;
}

}  // namespace hscloc
