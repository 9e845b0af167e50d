// `hscloc pipeline` against the commands it chains, run by hand, on the Lund photos; its bad-input
// answers as a process.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <sstream>

#include "tests/hscloc_process.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::ReadText;
using testing::RunHscloc;

std::vector<std::string> SortedLines(const fs::path& path) {
  std::vector<std::string> lines;
  std::istringstream text(ReadText(path));
  for (std::string line; std::getline(text, line);) lines.push_back(line);
  std::sort(lines.begin(), lines.end());
  return lines;
}

// The same features, model, map, network and poses, whichever way they are made: a short
// training with a fixed seed and thread count gives the same network on one machine.
TEST(PipelineCliTest, LundGivesTheSubmissionOfTheCommandsRunByHand) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir dir;
  const std::string training = "--iterations 60 --seed 5 --threads 2";
  const fs::path out = dir / "pipeline";
  ASSERT_EQ(RunHscloc(fmt::format("pipeline --dataset {} --feature xfeat --out {} --colmap {} {}",
                                  lund.string(), out.string(), colmap, training),
                      dir / "pipeline.log"),
            0)
      << ReadText(dir / "pipeline.log");
  const std::string log = ReadText(dir / "pipeline.log");
  EXPECT_THAT(log, HasSubstr("[1/5] features: 29 photos"));
  EXPECT_THAT(log, HasSubstr("[4/5] network: 60 iterations"));
  EXPECT_THAT(log, HasSubstr("against the dataset's ground truth"));

  const fs::path hand = dir / "hand";
  const std::vector<std::string> commands = {
      fmt::format("extract --images {0}/images --feature xfeat --out {1}/features.h5",
                  lund.string(), hand.string()),
      fmt::format("triangulate --model {0}/map --features {1}/features.h5 --images {0}/images "
                  "--out {1}/model --colmap {2}",
                  lund.string(), hand.string(), colmap),
      fmt::format("build-map --model {0}/model --features {0}/features.h5 --out {0}/map",
                  hand.string()),
      fmt::format("train --map {}/map {}", hand.string(), training),
      fmt::format("localize --map {0}/map --queries {1}/queries_with_intrinsics.txt --features "
                  "{0}/features.h5 --out {0}/submission.txt --matcher hsc",
                  hand.string(), lund.string())};
  for (const std::string& command : commands) {
    ASSERT_EQ(RunHscloc(command, dir / "hand.log"), 0) << command << "\n"
                                                       << ReadText(dir / "hand.log");
  }
  EXPECT_EQ(SortedLines(out / "submission.txt"), SortedLines(hand / "submission.txt"));

  ASSERT_EQ(RunHscloc(fmt::format("pipeline --dataset {} --feature xfeat --out {} --colmap {} {}",
                                  lund.string(), out.string(), colmap, training),
                      dir / "rerun.log"),
            0);
  EXPECT_THAT(ReadText(dir / "rerun.log"), HasSubstr("nothing to do"));
}

TEST(PipelineCliTest, BadInputFailsWithAClearMessageAndWritesNothing) {
  testing::TempDir dir;
  fs::create_directories(dir / "photos" / "images");
  EXPECT_EQ(RunHscloc(fmt::format("pipeline --dataset {} --out {}", (dir / "photos").string(),
                                  (dir / "out").string()),
                      dir / "layout.log"),
            2);
  EXPECT_THAT(ReadText(dir / "layout.log"), HasSubstr("is not a dataset"));
  EXPECT_FALSE(fs::exists(dir / "out"));
  EXPECT_NE(RunHscloc(fmt::format("pipeline --dataset {} --out {} --feature orb",
                                  (dir / "photos").string(), (dir / "out").string()),
                      dir / "feature.log"),
            0);
  EXPECT_THAT(ReadText(dir / "feature.log"), HasSubstr("--feature"));
}

}  // namespace
}  // namespace hscloc
