#include "map/map_bundle.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <optional>
#include <random>
#include <stdexcept>

#include "util/sha256.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

using Blobs = std::map<std::string, std::string>;

std::string RandomBytes(size_t size, uint32_t seed) {
  std::mt19937 random(seed);
  std::string bytes(size, '\0');
  for (char& c : bytes) c = static_cast<char>(random());
  return bytes;
}

nlohmann::json NestedMetadata() {
  return {{"num_images", 12},
          {"scene", "synthetic city"},
          {"options", {{"vocabulary", {{"depth", 6}, {"branching", 10}}}, {"scale_m", 0.25}}},
          {"image_ids", {1, 2, 3, 5, 8}}};
}

Blobs SampleBlobs() {
  return {{"empty.bin", ""},
          {"points3D.bin", RandomBytes(4096, 1)},
          {"tree.bin", RandomBytes(10 * 1024 * 1024, 2)},
          {"names.txt", "image_0001.jpg\nimage_0002.jpg\n"}};
}

void WriteBundle(const fs::path& dir, const Blobs& blobs,
                 const nlohmann::json& metadata = nlohmann::json::object()) {
  MapBundleWriter writer(dir);
  for (const auto& [name, bytes] : blobs) {
    writer.AddBlob(name, [&bytes = bytes](std::ostream& out) { out << bytes; });
  }
  writer.metadata() = metadata;
  writer.Commit();
}

std::string ReadFile(const fs::path& path) {
  std::ifstream file(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
}

void WriteFile(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

// The names in `dir`, sorted: shows leftover staging or old directories next to a bundle.
std::vector<std::string> EntryNames(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) names.push_back(entry.path().filename());
  std::sort(names.begin(), names.end());
  return names;
}

std::string OpenError(const fs::path& dir) {
  try {
    MapBundle::Open(dir);
  } catch (const std::invalid_argument& error) {
    return error.what();
  }
  ADD_FAILURE() << "opening " << dir << " did not throw";
  return "";
}

void ExpectBlobs(const MapBundle& bundle, const Blobs& expected) {
  std::vector<std::string> expected_names;
  for (const auto& [name, bytes] : expected) expected_names.push_back(name);
  EXPECT_EQ(bundle.BlobNames(), expected_names);
  for (const auto& [name, bytes] : expected) {
    ASSERT_TRUE(bundle.HasBlob(name)) << name;
    EXPECT_EQ(bundle.BlobSize(name), bytes.size()) << name;
    EXPECT_TRUE(bundle.Blob(name) == bytes) << name << " differs";
  }
}

void EditManifest(const fs::path& dir, const std::function<void(nlohmann::json&)>& edit) {
  nlohmann::json manifest = nlohmann::json::parse(ReadFile(dir / "manifest.json"));
  edit(manifest);
  WriteFile(dir / "manifest.json", manifest.dump());
}

TEST(MapBundle, RoundTripsBlobsAndMetadata) {
  testing::TempDir temp;
  const Blobs blobs = SampleBlobs();
  WriteBundle(temp / "map", blobs, NestedMetadata());

  const MapBundle bundle = MapBundle::Open(temp / "map");
  ExpectBlobs(bundle, blobs);
  EXPECT_EQ(bundle.metadata(), NestedMetadata());
  EXPECT_EQ(bundle.manifest().at("format"), "hscloc-map");
  EXPECT_EQ(bundle.manifest().at("format_version"), kMapBundleFormatVersion);
  EXPECT_EQ(bundle.manifest().at("files").at("tree.bin").at("sha256"),
            Sha256Hex(blobs.at("tree.bin")));
  EXPECT_EQ(bundle.manifest().at("files").at("tree.bin").at("bytes"), 10 * 1024 * 1024);
  EXPECT_FALSE(bundle.HasBlob("absent.bin"));
  try {
    bundle.Blob("absent.bin");
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("absent.bin"));
  }
}

TEST(MapBundle, OpensOnlyTheBlobsAskedForAndNeverReadsTheOthers) {
  testing::TempDir temp;
  const Blobs blobs = SampleBlobs();
  WriteBundle(temp / "map", blobs);
  // A corrupt blob that is not asked for is never read, so it cannot stop the others.
  std::string corrupt = blobs.at("points3D.bin");
  corrupt[7] ^= 0x01;
  WriteFile(temp / "map" / "points3D.bin", corrupt);
  MapBundle bundle =
      MapBundle::Open(temp / "map", std::vector<std::string>{"tree.bin", "x.bin"}, 2);
  EXPECT_TRUE(bundle.Blob("tree.bin") == blobs.at("tree.bin"));
  EXPECT_TRUE(bundle.HasBlob("points3D.bin"));
  EXPECT_EQ(bundle.BlobSize("points3D.bin"), blobs.at("points3D.bin").size());
  EXPECT_FALSE(bundle.HasBlob("x.bin"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { bundle.Blob("points3D.bin"); }),
              HasSubstr("blob 'points3D.bin' was not read"));
  // Taken, the bytes leave the bundle.
  EXPECT_TRUE(bundle.TakeBlob("tree.bin") == blobs.at("tree.bin"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { bundle.Blob("tree.bin"); }),
              HasSubstr("blob 'tree.bin' was not read"));
  // Asked for, the corrupt one is refused, whichever thread verifies it.
  for (const int threads : {1, 2, 8}) {
    EXPECT_THAT(testing::InvalidArgumentMessage(
                    [&] { MapBundle::Open(temp / "map", std::nullopt, threads); }),
                HasSubstr("blob 'points3D.bin' is corrupt (sha256 mismatch)"))
        << threads;
  }
}

TEST(MapBundle, AcceptsATrailingSlashAndIgnoresUnlistedFiles) {
  testing::TempDir temp;
  WriteBundle(temp.path().string() + "/map/", {{"a.bin", "abc"}});
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("map"));
  WriteFile(temp / "map" / "notes.txt", "left by hand");
  ExpectBlobs(MapBundle::Open(temp.path().string() + "/map/"), {{"a.bin", "abc"}});
}

TEST(MapBundle, FlippedByteInAnyBlobNamesThatBlob) {
  testing::TempDir temp;
  const Blobs blobs = SampleBlobs();
  for (const auto& [name, bytes] : blobs) {
    if (bytes.empty()) continue;
    const fs::path dir = temp / ("map_" + name);
    WriteBundle(dir, blobs);
    std::string corrupt = bytes;
    corrupt[corrupt.size() / 2] ^= 0x01;
    WriteFile(dir / name, corrupt);
    const std::string error = OpenError(dir);
    EXPECT_THAT(error, HasSubstr("map bundle " + dir.string() + ": blob '" + name +
                                 "' is corrupt (sha256 mismatch)"));
  }
}

TEST(MapBundle, TruncatedBlobNamesItAndBothSizes) {
  testing::TempDir temp;
  WriteBundle(temp / "map", SampleBlobs());
  fs::resize_file(temp / "map" / "points3D.bin", 1000);
  EXPECT_THAT(OpenError(temp / "map"),
              HasSubstr("blob 'points3D.bin' has 1000 bytes, manifest says 4096"));
}

TEST(MapBundle, MissingBlobIsNamed) {
  testing::TempDir temp;
  WriteBundle(temp / "map", SampleBlobs());
  fs::remove(temp / "map" / "empty.bin");
  EXPECT_THAT(OpenError(temp / "map"), HasSubstr("blob 'empty.bin' is missing"));
}

TEST(MapBundle, MissingManifestOrDirectoryIsNamed) {
  testing::TempDir temp;
  WriteBundle(temp / "map", SampleBlobs());
  fs::remove(temp / "map" / "manifest.json");
  EXPECT_THAT(OpenError(temp / "map"),
              HasSubstr("map bundle " + (temp / "map").string() + ": manifest.json is missing"));
  EXPECT_THAT(OpenError(temp / "nowhere"), HasSubstr("nowhere: no such directory"));
}

TEST(MapBundle, CorruptedManifestIsNamed) {
  testing::TempDir temp;
  WriteBundle(temp / "map", SampleBlobs());
  WriteFile(temp / "map" / "manifest.json", "{\"format\": \"hscloc-map\", \"files\": {");
  EXPECT_THAT(OpenError(temp / "map"), HasSubstr("manifest.json is not valid JSON"));

  WriteBundle(temp / "map", SampleBlobs());
  EditManifest(temp / "map", [](nlohmann::json& manifest) {
    manifest["files"]["tree.bin"]["bytes"] = "ten megabytes";
  });
  EXPECT_THAT(OpenError(temp / "map"), HasSubstr("malformed entry for blob 'tree.bin'"));

  WriteBundle(temp / "map", SampleBlobs());
  EditManifest(temp / "map", [](nlohmann::json& manifest) { manifest.erase("files"); });
  EXPECT_THAT(OpenError(temp / "map"), HasSubstr("manifest.json is malformed"));
}

TEST(MapBundle, WrongFormatOrVersionIsNamed) {
  testing::TempDir temp;
  WriteBundle(temp / "map", SampleBlobs());
  EditManifest(temp / "map", [](nlohmann::json& manifest) {
    manifest["format_version"] = kMapBundleFormatVersion + 1;
  });
  EXPECT_THAT(OpenError(temp / "map"),
              HasSubstr(fmt::format("manifest.json has format_version {}, newer than this build",
                                    kMapBundleFormatVersion + 1)));

  EditManifest(temp / "map", [](nlohmann::json& manifest) {
    manifest["format_version"] = kMapBundleFormatVersion - 1;
  });
  EXPECT_THAT(OpenError(temp / "map"), HasSubstr("older than this build reads"));

  EditManifest(temp / "map", [](nlohmann::json& manifest) {
    manifest["format_version"] = kMapBundleFormatVersion;
    manifest["format"] = "colmap-sparse";
  });
  EXPECT_THAT(OpenError(temp / "map"),
              HasSubstr("manifest.json has format 'colmap-sparse', expected 'hscloc-map'"));
}

TEST(MapBundle, ManifestNamingAFileOutsideTheBundleIsRejected) {
  testing::TempDir temp;
  WriteFile(temp / "secret.txt", "abc");
  WriteBundle(temp / "map", {{"a.bin", "abc"}});
  EditManifest(temp / "map", [](nlohmann::json& manifest) {
    manifest["files"]["../secret.txt"] = manifest["files"]["a.bin"];
  });
  EXPECT_THAT(OpenError(temp / "map"), HasSubstr("invalid blob name '../secret.txt'"));
}

TEST(MapBundleWriter, DestroyedWithoutCommitLeavesNothing) {
  testing::TempDir temp;
  {
    MapBundleWriter writer(temp / "map");
    writer.AddBlob("a.bin", [](std::ostream& out) { out << "abc"; });
    EXPECT_FALSE(fs::exists(temp / "map"));
    ASSERT_EQ(EntryNames(temp.path()).size(), 1u);
    EXPECT_THAT(EntryNames(temp.path())[0], HasSubstr("map.staging-"));
  }
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre());
}

TEST(MapBundleWriter, MovedWriterKeepsItsStagingDirectory) {
  testing::TempDir temp;
  std::optional<MapBundleWriter> moved;
  {
    MapBundleWriter writer(temp / "map");
    writer.AddBlob("a.bin", [](std::ostream& out) { out << "abc"; });
    moved.emplace(std::move(writer));
  }
  moved->Commit();
  ExpectBlobs(MapBundle::Open(temp / "map"), {{"a.bin", "abc"}});
}

TEST(MapBundleWriter, CommitReplacesAnExistingBundleCompletely) {
  testing::TempDir temp;
  WriteBundle(temp / "map", {{"a.bin", "old a"}, {"b.bin", "old b"}}, {{"version", "old"}});
  const Blobs new_blobs = {{"b.bin", "new b"}, {"c.bin", RandomBytes(100000, 3)}};
  WriteBundle(temp / "map", new_blobs, {{"version", "new"}});

  const MapBundle bundle = MapBundle::Open(temp / "map");
  ExpectBlobs(bundle, new_blobs);
  EXPECT_EQ(bundle.metadata(), nlohmann::json({{"version", "new"}}));
  EXPECT_FALSE(fs::exists(temp / "map" / "a.bin"));
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("map"));
  EXPECT_THAT(EntryNames(temp / "map"), ElementsAre("b.bin", "c.bin", "manifest.json"));
}

TEST(MapBundleWriter, ThrowingWriteLeavesTheOldBundleIntact) {
  testing::TempDir temp;
  const Blobs blobs = SampleBlobs();
  WriteBundle(temp / "map", blobs, NestedMetadata());
  {
    MapBundleWriter writer(temp / "map");
    writer.AddBlob("tree.bin", [](std::ostream& out) { out << "a new tree"; });
    EXPECT_THROW(writer.AddBlob("points3D.bin",
                                [](std::ostream& out) {
                                  out << "half of it";
                                  throw std::runtime_error("out of memory");
                                }),
                 std::runtime_error);
  }
  const MapBundle bundle = MapBundle::Open(temp / "map");
  ExpectBlobs(bundle, blobs);
  EXPECT_EQ(bundle.metadata(), NestedMetadata());
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("map"));
}

TEST(MapBundleWriter, FailedStreamNamesTheBlob) {
  testing::TempDir temp;
  MapBundleWriter writer(temp / "map");
  try {
    writer.AddBlob("tree.bin", [](std::ostream& out) { out.setstate(std::ios::badbit); });
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("blob 'tree.bin' could not be written"));
  }
  writer.Commit();
  EXPECT_THAT(MapBundle::Open(temp / "map").BlobNames(), ElementsAre());
}

TEST(MapBundleWriter, ThrowingRewriteKeepsTheStagedBlob) {
  testing::TempDir temp;
  MapBundleWriter writer(temp / "map");
  writer.AddBlob("a.bin", [](std::ostream& out) { out << "first"; });
  EXPECT_THROW(writer.AddBlob("a.bin",
                              [](std::ostream& out) {
                                out << "second";
                                throw std::runtime_error("interrupted");
                              }),
               std::runtime_error);
  writer.Commit();
  ExpectBlobs(MapBundle::Open(temp / "map"), {{"a.bin", "first"}});
  EXPECT_THAT(EntryNames(temp / "map"), ElementsAre("a.bin", "manifest.json"));
}

TEST(MapBundleWriter, RejectsBadBlobNames) {
  testing::TempDir temp;
  MapBundleWriter writer(temp / "map");
  const auto write = [](std::ostream& out) { out << "x"; };
  for (const std::string name :
       {"", "a/b.bin", "/abs.bin", "manifest.json", ".hidden", "..", "."}) {
    try {
      writer.AddBlob(name, write);
      ADD_FAILURE() << "blob name '" << name << "' was accepted";
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr("invalid blob name '" + name + "'"));
    }
  }
  writer.AddBlob("weights.pt", write);
  writer.Commit();
  EXPECT_THAT(EntryNames(temp / "map"), ElementsAre("manifest.json", "weights.pt"));
}

TEST(MapBundleWriter, RefusesToReplaceADirectoryThatIsNotABundle) {
  testing::TempDir temp;
  fs::create_directories(temp / "photos");
  WriteFile(temp / "photos" / "holiday.jpg", "jpeg");
  try {
    MapBundleWriter writer(temp / "photos");
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("is not a map bundle"));
  }
  EXPECT_EQ(ReadFile(temp / "photos" / "holiday.jpg"), "jpeg");
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("photos"));

  fs::create_directories(temp / "empty");
  WriteBundle(temp / "empty", {{"a.bin", "abc"}});
  ExpectBlobs(MapBundle::Open(temp / "empty"), {{"a.bin", "abc"}});
}

TEST(MapBundleWriter, UpdateAddsABlobAndKeepsTheOthers) {
  testing::TempDir temp;
  const Blobs blobs = SampleBlobs();
  WriteBundle(temp / "map", blobs, NestedMetadata());
  const std::string weights = RandomBytes(50000, 4);
  {
    MapBundleWriter writer = MapBundleWriter::Update(temp / "map");
    EXPECT_EQ(writer.metadata(), NestedMetadata());
    writer.AddBlob("weights.pt", [&](std::ostream& out) { out << weights; });
    writer.metadata()["weights"] = {{"epochs", 30}};
    // Until Commit() the old bundle is what readers see.
    ExpectBlobs(MapBundle::Open(temp / "map"), blobs);
    writer.Commit();
  }
  Blobs expected = blobs;
  expected["weights.pt"] = weights;
  nlohmann::json expected_metadata = NestedMetadata();
  expected_metadata["weights"] = {{"epochs", 30}};
  const MapBundle bundle = MapBundle::Open(temp / "map");
  ExpectBlobs(bundle, expected);
  EXPECT_EQ(bundle.metadata(), expected_metadata);
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("map"));
}

TEST(MapBundleWriter, UpdateReplacingABlobNeverWritesThroughToTheOldBundle) {
  testing::TempDir temp;
  const Blobs blobs = SampleBlobs();
  WriteBundle(temp / "map", blobs);
  {
    MapBundleWriter writer = MapBundleWriter::Update(temp / "map");
    writer.AddBlob("tree.bin", [](std::ostream& out) { out << "retrained tree"; });
  }
  ExpectBlobs(MapBundle::Open(temp / "map"), blobs);

  {
    MapBundleWriter writer = MapBundleWriter::Update(temp / "map");
    writer.AddBlob("tree.bin", [](std::ostream& out) { out << "retrained tree"; });
    writer.Commit();
  }
  Blobs expected = blobs;
  expected["tree.bin"] = "retrained tree";
  ExpectBlobs(MapBundle::Open(temp / "map"), expected);
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("map"));
}

TEST(MapBundleWriter, UpdateOfACorruptBundleThrows) {
  testing::TempDir temp;
  WriteBundle(temp / "map", SampleBlobs());
  std::string tree = ReadFile(temp / "map" / "tree.bin");
  tree[12345] ^= 0x40;
  WriteFile(temp / "map" / "tree.bin", tree);
  try {
    MapBundleWriter::Update(temp / "map");
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("blob 'tree.bin' is corrupt (sha256 mismatch)"));
  }
  EXPECT_THAT(EntryNames(temp.path()), ElementsAre("map"));
  EXPECT_THROW(MapBundleWriter::Update(temp / "nowhere"), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
