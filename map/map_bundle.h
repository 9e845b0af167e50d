// A map bundle: one directory holding `manifest.json` and binary blobs. The manifest records the
// format version, free-form metadata (counts, options) and the size and SHA-256 of every blob.
//
// Writing is atomic: blobs go into a sibling temporary directory that replaces the bundle only in
// Commit(), so a crash never leaves a half-written map under the bundle's name. Opening verifies
// the format version and every blob's size and checksum, and names the bad file.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace hscloc {

inline constexpr int kMapBundleFormatVersion = 1;

class MapBundleWriter {
 public:
  // Starts a new bundle that will replace `bundle_dir` on Commit(). Throws when `bundle_dir` exists
  // and is neither empty nor a map bundle, so that a mistyped path never deletes unrelated files.
  explicit MapBundleWriter(std::filesystem::path bundle_dir);
  // Starts from an existing bundle: its blobs and manifest are carried over (hard links where the
  // file system allows, else copies) unless replaced; used to add trained weights to a map.
  static MapBundleWriter Update(const std::filesystem::path& bundle_dir);
  // Removes the temporary directory when Commit() was not reached.
  ~MapBundleWriter();
  MapBundleWriter(MapBundleWriter&&) noexcept;
  MapBundleWriter(const MapBundleWriter&) = delete;
  MapBundleWriter& operator=(const MapBundleWriter&) = delete;

  // Writes (or replaces) the blob `name` through `write`. `name` is a plain file name: not empty,
  // no '/', not starting with '.', not "manifest.json". Throws naming the blob when the stream
  // fails (disk full); when `write` throws, the bundle being staged keeps its earlier content.
  void AddBlob(const std::string& name, const std::function<void(std::ostream&)>& write);
  // Metadata recorded in the manifest under "metadata".
  nlohmann::json& metadata() { return metadata_; }

  // Writes the manifest (with every blob's size and SHA-256), syncs it to disk and moves the bundle
  // into place. An existing bundle is renamed aside and removed only once the new one is in place;
  // if the swap fails the old bundle is restored.
  void Commit();

 private:
  std::filesystem::path bundle_dir_;
  std::filesystem::path staging_dir_;  // empty once moved from
  std::string unique_suffix_;          // "<pid>-<random>", shared by the staging and old names
  nlohmann::json metadata_ = nlohmann::json::object();
  std::map<std::string, std::pair<uint64_t, std::string>> blobs_;  // name -> (size, sha256 hex)
  bool committed_ = false;
};

class MapBundle {
 public:
  // Reads the manifest and verifies the format version, then reads the blobs `blobs` names (every
  // blob of the manifest when nullopt; names the manifest lacks are skipped, HasBlob tells) into
  // buffers of their exact size and verifies each one's size and SHA-256, several blobs at once on
  // up to `num_threads` threads (<= 0: all cores). Throws std::invalid_argument naming the bundle
  // and the missing, truncated or corrupt file.
  static MapBundle Open(const std::filesystem::path& bundle_dir,
                        const std::optional<std::vector<std::string>>& blobs = std::nullopt,
                        int num_threads = 0);

  const std::filesystem::path& dir() const { return dir_; }
  const nlohmann::json& metadata() const { return metadata_; }
  const nlohmann::json& manifest() const { return manifest_; }
  // The SHA-256 (hex) of the manifest as read: it lists every blob's hash, so it names the bundle's
  // content (two bundles differ here whenever any byte of theirs does).
  const std::string& manifest_sha256() const { return manifest_sha256_; }
  // Whether the manifest lists the blob (read or not).
  bool HasBlob(const std::string& name) const { return sizes_.count(name) > 0; }
  std::vector<std::string> BlobNames() const;
  // The size the manifest records; throws naming the blob when absent.
  uint64_t BlobSize(const std::string& name) const;
  // The blob's bytes, as verified at Open(); throws naming the blob when absent, not read or taken.
  const std::string& Blob(const std::string& name) const;
  // Moves the blob's bytes out, so that they are freed once parsed; Blob() then throws.
  std::string TakeBlob(const std::string& name);

 private:
  std::filesystem::path dir_;
  nlohmann::json manifest_;
  std::string manifest_sha256_;
  nlohmann::json metadata_;
  std::map<std::string, uint64_t> sizes_;     // every blob of the manifest
  std::map<std::string, std::string> blobs_;  // the blobs read
};

}  // namespace hscloc
