// COLMAP model I/O against the real sets and the real colmap binary.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <regex>
#include <string>

#include "scene/colmap_io.h"
#include "scene/colmap_io_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using namespace colmap_io_testing;

struct RealModel {
  const char* name;
  const char* subdirectory;
  ColmapFormat format;
  size_t num_images;
  size_t num_points3D;
  size_t num_observations;  // the data set's README, from colmap model_analyzer
};

// Names the parameter in test listings (ctest shows it) instead of dumping its bytes.
void PrintTo(const RealModel& model, std::ostream* stream) { *stream << model.subdirectory; }

class ColmapIoRealData : public ::testing::TestWithParam<RealModel> {
 protected:
  // Runs COLMAP, failing the test with its output when it fails.
  static void RunColmap(const std::string& colmap, const std::string& arguments,
                        const fs::path& log) {
    const int status = testing::RunCommand(colmap + " " + arguments, log.string());
    ASSERT_EQ(status, 0) << colmap << " " << arguments << "\n" << ReadFile(log);
  }

  static void ConvertWithColmap(const std::string& colmap, const fs::path& input,
                                const fs::path& output, ColmapFormat format, const fs::path& log) {
    fs::create_directories(output);
    RunColmap(colmap,
              fmt::format("model_converter --input_path '{}' --output_path '{}' --output_type {}",
                          input.string(), output.string(),
                          format == ColmapFormat::kBinary ? "BIN" : "TXT"),
              log);
  }
};

TEST_P(ColmapIoRealData, HasTheKnownCounts) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  EXPECT_EQ(DetectColmapFormat(dir), GetParam().format);
  const Reconstruction reconstruction = ReadColmapModel(dir);
  EXPECT_EQ(reconstruction.images.size(), GetParam().num_images);
  EXPECT_EQ(reconstruction.points3D.size(), GetParam().num_points3D);
  EXPECT_EQ(reconstruction.NumObservations(), GetParam().num_observations);
}

TEST_P(ColmapIoRealData, ReadsWhatColmapModelConverterWrites) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  HSCLOC_REQUIRE_COLMAP(colmap);
  const testing::TempDir temp;
  const ColmapFormat other =
      GetParam().format == ColmapFormat::kBinary ? ColmapFormat::kText : ColmapFormat::kBinary;
  ConvertWithColmap(colmap, dir, temp / "converted", other, temp / "colmap.log");
  if (HasFatalFailure()) return;
  EXPECT_EQ(DetectColmapFormat(temp / "converted"), other);
  // COLMAP renormalizes quaternions and writes text with 17 digits.
  EXPECT_TRUE(SameReconstruction(ReadColmapModel(dir), ReadColmapModel(temp / "converted"), 1e-12));
}

TEST_P(ColmapIoRealData, ColmapReadsOurBinaryModel) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  HSCLOC_REQUIRE_COLMAP(colmap);
  const testing::TempDir temp;
  const Reconstruction reconstruction = ReadColmapModel(dir);
  WriteColmapModel(reconstruction, temp / "ours", ColmapFormat::kBinary);
  RunColmap(colmap, fmt::format("model_analyzer --path '{}'", (temp / "ours").string()),
            temp / "analyzer.log");
  if (HasFatalFailure()) return;
  const std::string log = ReadFile(temp / "analyzer.log");
  const auto count = [&](const std::string& label) -> long {
    std::smatch match;
    if (!std::regex_search(log, match, std::regex("\\b" + label + ": ([0-9]+)"))) return -1;
    return std::stol(match[1]);
  };
  EXPECT_EQ(count("Registered images"), static_cast<long>(reconstruction.images.size())) << log;
  EXPECT_EQ(count("Points"), static_cast<long>(reconstruction.points3D.size())) << log;
  EXPECT_EQ(count("Observations"), static_cast<long>(reconstruction.NumObservations())) << log;
}

TEST_P(ColmapIoRealData, ColmapConvertsOurTextModelBack) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  HSCLOC_REQUIRE_COLMAP(colmap);
  const testing::TempDir temp;
  const Reconstruction reconstruction = ReadColmapModel(dir);
  WriteColmapModel(reconstruction, temp / "ours", ColmapFormat::kText);
  ConvertWithColmap(colmap, temp / "ours", temp / "back", ColmapFormat::kBinary,
                    temp / "colmap.log");
  if (HasFatalFailure()) return;
  EXPECT_TRUE(SameReconstruction(reconstruction, ReadColmapModel(temp / "back"), 1e-12));
}

// Binary files are cut anywhere; text files at line boundaries after the header, where only its
// count can tell.
TEST_P(ColmapIoRealData, TruncatedFilesFailNamingTheFile) {
  HSCLOC_REQUIRE_REAL_DATA(dir, GetParam().subdirectory);
  const testing::TempDir temp;
  const bool binary = GetParam().format == ColmapFormat::kBinary;
  const std::string extension = binary ? ".bin" : ".txt";
  for (const char* stem : {"cameras", "images", "points3D"}) {
    const std::string name = stem + extension;
    const std::string bytes = ReadFile(dir / name);
    for (size_t size : {size_t{0}, size_t{5}, size_t{8}, size_t{45}, bytes.size() / 3,
                        bytes.size() / 2, bytes.size() - 1}) {
      if (!binary) {
        // Cut before the header's count, a file is an empty model: COLMAP's too.
        const size_t header_end = bytes.find('\n', bytes.find("# Number of")) + 1;
        size = std::max(header_end, bytes.rfind('\n', size == 0 ? 0 : size - 1) + 1);
      }
      fs::create_directories(temp / "cut");
      for (const char* other : {"cameras", "images", "points3D"}) {
        const std::string other_name = other + extension;
        WriteFile(temp / "cut" / other_name,
                  other_name == name ? bytes.substr(0, size) : ReadFile(dir / other_name));
      }
      const std::string message =
          testing::InvalidArgumentMessage([&] { ReadColmapModel(temp / "cut"); });
      EXPECT_THAT(message, HasSubstr((temp / "cut" / name).string())) << size;
      if (binary) {
        EXPECT_THAT(message, HasSubstr("truncated")) << size;
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(
    Sets, ColmapIoRealData,
    ::testing::Values(
        RealModel{"fountain", "fountain-P11/map", ColmapFormat::kBinary, 9, 2302, 7828},
        RealModel{"lund", "lund/map", ColmapFormat::kBinary, 24, 532, 1703},
        RealModel{"maupertuis", "maupertuis/map_txt", ColmapFormat::kText, 4, 1039, 3355}),
    [](const ::testing::TestParamInfo<RealModel>& info) { return std::string(info.param.name); });

}  // namespace
}  // namespace hscloc
