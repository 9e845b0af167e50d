#include "map/map_bundle.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>
#include <system_error>

#include "map/map_blobs.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/sha256.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

constexpr const char* kManifestName = map_blobs::kManifest;
constexpr char kFormatName[] = "hscloc-map";
constexpr char kCreatedBy[] = "hscloc 0.1.0";

struct ManifestEntry {
  uint64_t bytes = 0;
  std::string sha256;
};

struct Manifest {
  nlohmann::json json;
  std::map<std::string, ManifestEntry> files;
  std::string sha256;  // of the manifest's bytes as read
};

bool IsValidBlobName(const std::string& name) {
  return !name.empty() && name.front() != '.' && name.find('/') == std::string::npos &&
         name.find('\0') == std::string::npos && name != kManifestName;
}

bool IsLowercaseSha256Hex(const std::string& text) {
  if (text.size() != 64) return false;
  for (const char c : text) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

// "out/map/" and "out/map" name the same bundle; the sibling paths need the second form.
fs::path NormalizedDir(const fs::path& dir) {
  fs::path normal = dir.lexically_normal();
  if (!normal.has_filename() && normal.has_parent_path()) normal = normal.parent_path();
  return normal;
}

fs::path SiblingPath(const fs::path& dir, const std::string& suffix) {
  return dir.parent_path() / (dir.filename().string() + suffix);
}

// Refuses anything but an absent path, an empty directory or an earlier bundle: Commit() deletes
// what it replaces.
void CheckReplaceable(const fs::path& dir) {
  std::error_code error;
  const fs::file_status status = fs::symlink_status(dir, error);
  if (!fs::exists(status)) return;
  if (fs::is_symlink(status)) {
    ThrowInvalidArgument(
        "map bundle {}: is a symbolic link; write the bundle to its target instead", dir.string());
  }
  if (!fs::is_directory(status)) {
    ThrowInvalidArgument("map bundle {}: exists and is not a directory; refusing to replace it",
                         dir.string());
  }
  if (fs::exists(dir / kManifestName) || fs::is_empty(dir)) return;
  ThrowInvalidArgument(
      "map bundle {}: exists and is not a map bundle (no {}); refusing to replace it", dir.string(),
      kManifestName);
}

void SyncFile(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) ThrowInvalidArgument("cannot open {} to sync it: {}", path.string(), strerror(errno));
  const int result = ::fsync(fd);
  const int sync_errno = errno;
  ::close(fd);
  if (result != 0) ThrowInvalidArgument("cannot sync {}: {}", path.string(), strerror(sync_errno));
}

// Best effort: some file systems refuse fsync on a directory, and the data itself is already
// synced; only the durability of the rename is at stake.
void SyncDirectory(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

Manifest ReadManifest(const fs::path& dir) {
  std::error_code error;
  if (!fs::is_directory(dir, error)) {
    ThrowInvalidArgument("map bundle {}: no such directory", dir.string());
  }
  const fs::path path = dir / kManifestName;
  std::ifstream file(path, std::ios::binary);
  if (!file) {
    if (!fs::exists(path, error)) {
      ThrowInvalidArgument("map bundle {}: {} is missing", dir.string(), kManifestName);
    }
    ThrowInvalidArgument("map bundle {}: {} cannot be read", dir.string(), kManifestName);
  }
  const std::string text((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());

  Manifest manifest;
  manifest.sha256 = Sha256Hex(text);
  try {
    manifest.json = nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& parse_error) {
    ThrowInvalidArgument("map bundle {}: {} is not valid JSON ({})", dir.string(), kManifestName,
                         parse_error.what());
  }

  // Every problem below is a std::invalid_argument naming the field; a wrongly typed field surfaces
  // as a nlohmann exception, turned into the same kind of error at the end.
  try {
    const nlohmann::json& json = manifest.json;
    if (!json.is_object()) {
      ThrowInvalidArgument("map bundle {}: {} is not a JSON object", dir.string(), kManifestName);
    }
    const std::string format = json.at("format").get<std::string>();
    if (format != kFormatName) {
      ThrowInvalidArgument("map bundle {}: {} has format '{}', expected '{}'", dir.string(),
                           kManifestName, format, kFormatName);
    }
    const nlohmann::json& version = json.at("format_version");
    if (!version.is_number_integer()) {
      ThrowInvalidArgument("map bundle {}: {} has a format_version that is not an integer ({})",
                           dir.string(), kManifestName, version.dump());
    }
    const int64_t format_version = version.get<int64_t>();
    if (format_version > kMapBundleFormatVersion) {
      ThrowInvalidArgument(
          "map bundle {}: {} has format_version {}, newer than this build reads ({}); use a newer "
          "hscloc",
          dir.string(), kManifestName, format_version, kMapBundleFormatVersion);
    }
    if (format_version < kMapBundleFormatVersion) {
      ThrowInvalidArgument(
          "map bundle {}: {} has format_version {}, older than this build reads ({}); rebuild the "
          "map",
          dir.string(), kManifestName, format_version, kMapBundleFormatVersion);
    }
    if (!json.at("metadata").is_object()) {
      ThrowInvalidArgument("map bundle {}: {} has a metadata field that is not an object",
                           dir.string(), kManifestName);
    }
    const nlohmann::json& files = json.at("files");
    if (!files.is_object()) {
      ThrowInvalidArgument("map bundle {}: {} has a files field that is not an object",
                           dir.string(), kManifestName);
    }
    for (const auto& [name, entry] : files.items()) {
      // A name such as "../x" would make Open() read outside the bundle.
      if (!IsValidBlobName(name)) {
        ThrowInvalidArgument("map bundle {}: {} lists an invalid blob name '{}'", dir.string(),
                             kManifestName, name);
      }
      const nlohmann::json& bytes = entry.at("bytes");
      const std::string sha256 = entry.at("sha256").get<std::string>();
      if (!bytes.is_number_unsigned() || !IsLowercaseSha256Hex(sha256)) {
        ThrowInvalidArgument("map bundle {}: {} has a malformed entry for blob '{}': {}",
                             dir.string(), kManifestName, name, entry.dump());
      }
      manifest.files[name] = ManifestEntry{bytes.get<uint64_t>(), sha256};
    }
  } catch (const nlohmann::json::exception& json_error) {
    ThrowInvalidArgument("map bundle {}: {} is malformed ({})", dir.string(), kManifestName,
                         json_error.what());
  }
  return manifest;
}

[[noreturn]] void ThrowBadBlob(const fs::path& dir, const std::string& name,
                               const std::string& problem) {
  ThrowInvalidArgument("map bundle {}: blob '{}' {}", dir.string(), name, problem);
}

void CheckBlobSize(const fs::path& dir, const std::string& name, const ManifestEntry& entry) {
  const fs::path path = dir / name;
  std::error_code error;
  const fs::file_status status = fs::status(path, error);
  if (!fs::exists(status)) ThrowBadBlob(dir, name, "is missing");
  if (!fs::is_regular_file(status)) ThrowBadBlob(dir, name, "is not a regular file");
  const uint64_t size = fs::file_size(path);
  if (size != entry.bytes) {
    ThrowBadBlob(dir, name, fmt::format("has {} bytes, manifest says {}", size, entry.bytes));
  }
}

void CheckBlobDigest(const fs::path& dir, const std::string& name, const ManifestEntry& entry,
                     const std::string& sha256) {
  if (sha256 != entry.sha256) ThrowBadBlob(dir, name, "is corrupt (sha256 mismatch)");
}

std::string ReadBlob(const fs::path& dir, const std::string& name, uint64_t size) {
  std::ifstream file(dir / name, std::ios::binary);
  std::string bytes(size, '\0');
  file.read(bytes.data(), static_cast<std::streamsize>(size));
  if (!file || static_cast<uint64_t>(file.gcount()) != size) {
    ThrowBadBlob(dir, name, "cannot be read");
  }
  return bytes;
}

}  // namespace

MapBundleWriter::MapBundleWriter(std::filesystem::path bundle_dir)
    : bundle_dir_(NormalizedDir(fs::absolute(bundle_dir))) {
  THROW_CHECK_MSG(bundle_dir_.has_filename() && bundle_dir_.has_parent_path(),
                  "map bundle {}: not a usable bundle directory", bundle_dir.string());
  CheckReplaceable(bundle_dir_);
  std::random_device random;
  unique_suffix_ = fmt::format("{}-{:08x}", ::getpid(), random());
  fs::create_directories(bundle_dir_.parent_path());
  // A sibling of the bundle, so that Commit() is a rename within one file system.
  const fs::path staging_dir = SiblingPath(bundle_dir_, ".staging-" + unique_suffix_);
  const bool created = fs::create_directory(staging_dir);
  THROW_CHECK_MSG(created, "staging directory {} already exists", staging_dir.string());
  staging_dir_ = staging_dir;
}

MapBundleWriter MapBundleWriter::Update(const std::filesystem::path& bundle_dir) {
  const fs::path dir = NormalizedDir(bundle_dir);
  const Manifest manifest = ReadManifest(dir);
  for (const auto& [name, entry] : manifest.files) {
    CheckBlobSize(dir, name, entry);
    CheckBlobDigest(dir, name, entry, Sha256HexOfFile(dir / name));
  }

  MapBundleWriter writer(dir);
  writer.metadata_ = manifest.json.at("metadata");
  for (const auto& [name, entry] : manifest.files) {
    const fs::path target = writer.staging_dir_ / name;
    std::error_code link_error;
    fs::create_hard_link(dir / name, target, link_error);
    if (link_error) fs::copy_file(dir / name, target);
    writer.blobs_[name] = {entry.bytes, entry.sha256};
  }
  return writer;
}

MapBundleWriter::~MapBundleWriter() {
  if (staging_dir_.empty() || committed_) return;
  std::error_code error;
  fs::remove_all(staging_dir_, error);
  if (error) {
    spdlog::warn("map bundle {}: cannot remove the staging directory {}: {}", bundle_dir_.string(),
                 staging_dir_.string(), error.message());
  }
}

MapBundleWriter::MapBundleWriter(MapBundleWriter&& other) noexcept
    : bundle_dir_(std::move(other.bundle_dir_)),
      staging_dir_(std::exchange(other.staging_dir_, fs::path())),
      unique_suffix_(std::move(other.unique_suffix_)),
      metadata_(std::move(other.metadata_)),
      blobs_(std::move(other.blobs_)),
      committed_(other.committed_) {}

void MapBundleWriter::AddBlob(const std::string& name,
                              const std::function<void(std::ostream&)>& write) {
  THROW_CHECK_MSG(!staging_dir_.empty() && !committed_, "map bundle {}: AddBlob('{}') after Commit",
                  bundle_dir_.string(), name);
  if (!IsValidBlobName(name)) {
    ThrowInvalidArgument(
        "map bundle {}: invalid blob name '{}' (a plain file name is required: not empty, no '/', "
        "not starting with '.', not '{}')",
        bundle_dir_.string(), name, kManifestName);
  }
  // Written under a temporary name and renamed over the blob: a blob carried over by Update() is a
  // hard link into the old bundle, which writing through it would alter; and a failed write leaves
  // the staged blob as it was.
  const fs::path blob_path = staging_dir_ / name;
  const fs::path partial_path = staging_dir_ / ("." + name + ".partial");
  try {
    std::ofstream out(partial_path, std::ios::binary | std::ios::trunc);
    if (!out) {
      ThrowInvalidArgument("map bundle {}: cannot create blob '{}' in {}", bundle_dir_.string(),
                           name, staging_dir_.string());
    }
    write(out);
    // close() flushes, and sets failbit when the final flush fails (disk full).
    out.close();
    if (!out) {
      ThrowInvalidArgument("map bundle {}: blob '{}' could not be written (disk full?)",
                           bundle_dir_.string(), name);
    }
    const uint64_t size = fs::file_size(partial_path);
    std::string sha256 = Sha256HexOfFile(partial_path);
    fs::rename(partial_path, blob_path);
    blobs_[name] = {size, std::move(sha256)};
  } catch (...) {
    std::error_code ignored;
    fs::remove(partial_path, ignored);
    throw;
  }
}

void MapBundleWriter::Commit() {
  THROW_CHECK_MSG(!staging_dir_.empty() && !committed_, "map bundle {}: Commit() called twice",
                  bundle_dir_.string());
  if (!metadata_.is_object()) {
    ThrowInvalidArgument("map bundle {}: metadata must be a JSON object, not {}",
                         bundle_dir_.string(), metadata_.type_name());
  }
  nlohmann::json files = nlohmann::json::object();
  for (const auto& [name, blob] : blobs_) {
    files[name] = {{"bytes", blob.first}, {"sha256", blob.second}};
  }
  const nlohmann::json manifest = {{"format", kFormatName},
                                   {"format_version", kMapBundleFormatVersion},
                                   {"created_by", kCreatedBy},
                                   {"metadata", metadata_},
                                   {"files", files}};
  const fs::path manifest_path = staging_dir_ / kManifestName;
  {
    std::ofstream out(manifest_path, std::ios::binary | std::ios::trunc);
    out << manifest.dump(2) << '\n';
    out.close();
    if (!out) {
      ThrowInvalidArgument("map bundle {}: cannot write {} (disk full?)", bundle_dir_.string(),
                           kManifestName);
    }
  }
  // Everything reaches the disk before the rename publishes it; otherwise a crash soon after could
  // leave a bundle whose directory entries survived but whose contents did not.
  for (const auto& [name, blob] : blobs_) SyncFile(staging_dir_ / name);
  SyncFile(manifest_path);
  SyncDirectory(staging_dir_);

  // Checked again: the target may have appeared since the constructor.
  CheckReplaceable(bundle_dir_);
  std::error_code error;
  const bool replacing = fs::exists(fs::symlink_status(bundle_dir_, error));
  const fs::path old_dir = SiblingPath(bundle_dir_, ".old-" + unique_suffix_);
  if (replacing) fs::rename(bundle_dir_, old_dir);
  try {
    fs::rename(staging_dir_, bundle_dir_);
  } catch (...) {
    if (replacing) {
      std::error_code restore_error;
      fs::rename(old_dir, bundle_dir_, restore_error);
      if (restore_error) {
        spdlog::error("map bundle {}: the previous bundle could not be moved back from {}: {}",
                      bundle_dir_.string(), old_dir.string(), restore_error.message());
      }
    }
    throw;
  }
  committed_ = true;
  SyncDirectory(bundle_dir_.parent_path());
  if (replacing) {
    fs::remove_all(old_dir, error);
    if (error) {
      spdlog::warn("map bundle {}: cannot remove the previous bundle {}: {}", bundle_dir_.string(),
                   old_dir.string(), error.message());
    }
  }
}

MapBundle MapBundle::Open(const std::filesystem::path& bundle_dir,
                          const std::optional<std::vector<std::string>>& blobs, int num_threads) {
  MapBundle bundle;
  bundle.dir_ = NormalizedDir(bundle_dir);
  Manifest manifest = ReadManifest(bundle.dir_);
  std::vector<std::pair<std::string, const ManifestEntry*>> wanted;
  for (const auto& [name, entry] : manifest.files) {
    bundle.sizes_.emplace(name, entry.bytes);
    if (!blobs || std::find(blobs->begin(), blobs->end(), name) != blobs->end()) {
      wanted.emplace_back(name, &entry);
    }
  }
  // Largest first, so that the threads finish together; a blob is read and hashed by one thread.
  std::sort(wanted.begin(), wanted.end(),
            [](const auto& a, const auto& b) { return a.second->bytes > b.second->bytes; });
  std::vector<std::string> bytes(wanted.size());
  std::atomic<size_t> next{0};
  ParallelFor(std::min<size_t>(wanted.size(), ResolveNumThreads(num_threads)), num_threads,
              [&](size_t, size_t) {
                for (size_t i; (i = next++) < wanted.size();) {
                  const auto& [name, entry] = wanted[i];
                  CheckBlobSize(bundle.dir_, name, *entry);
                  bytes[i] = ReadBlob(bundle.dir_, name, entry->bytes);
                  CheckBlobDigest(bundle.dir_, name, *entry, Sha256Hex(bytes[i]));
                }
              });
  for (size_t i = 0; i < wanted.size(); ++i) {
    bundle.blobs_.emplace(wanted[i].first, std::move(bytes[i]));
  }
  bundle.metadata_ = manifest.json.at("metadata");
  bundle.manifest_ = std::move(manifest.json);
  bundle.manifest_sha256_ = std::move(manifest.sha256);
  return bundle;
}

std::vector<std::string> MapBundle::BlobNames() const {
  std::vector<std::string> names;
  names.reserve(sizes_.size());
  for (const auto& [name, size] : sizes_) names.push_back(name);
  return names;
}

uint64_t MapBundle::BlobSize(const std::string& name) const {
  const auto it = sizes_.find(name);
  if (it == sizes_.end()) ThrowInvalidArgument("map bundle {}: no blob '{}'", dir_.string(), name);
  return it->second;
}

const std::string& MapBundle::Blob(const std::string& name) const {
  const auto it = blobs_.find(name);
  if (it == blobs_.end()) {
    ThrowInvalidArgument("map bundle {}: {}", dir_.string(),
                         HasBlob(name) ? fmt::format("blob '{}' was not read", name)
                                       : fmt::format("no blob '{}'", name));
  }
  return it->second;
}

std::string MapBundle::TakeBlob(const std::string& name) {
  std::string bytes = std::move(const_cast<std::string&>(Blob(name)));
  blobs_.erase(name);
  return bytes;
}

}  // namespace hscloc
