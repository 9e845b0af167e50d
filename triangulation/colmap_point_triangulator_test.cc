#include "triangulation/colmap_point_triangulator.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <stdexcept>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

TEST(ColmapPointTriangulator, AMissingExecutableIsNamedWithTheOptionThatSetsIt) {
  testing::TempDir temp;
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [] { FindColmap({.colmap_executable = "hscloc-no-such-colmap"}); }),
              HasSubstr("'hscloc-no-such-colmap' was not found on PATH"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                RunColmapPointTriangulator(
                    {temp / "a.db", temp.path(), temp / "in", temp / "out", temp / "log.txt"},
                    {.colmap_executable = "/nowhere/colmap"});
              }),
              HasSubstr("'/nowhere/colmap' was not found: install COLMAP 3.8 (apt-get install "
                        "colmap) or name it with --colmap PATH"));
}

TEST(ColmapPointTriangulator, AFailingRunReportsItsLog) {
  HSCLOC_REQUIRE_COLMAP(colmap);
  testing::TempDir temp;
  const ColmapPointTriangulatorPaths paths = {temp / "missing.db", temp.path(), temp / "no_model",
                                              temp / "out", temp / "colmap.log"};
  try {
    RunColmapPointTriangulator(paths, {.colmap_executable = colmap});
    ADD_FAILURE() << "expected a failure";
  } catch (const std::runtime_error& error) {
    EXPECT_THAT(error.what(), HasSubstr("point_triangulator failed (exit status"));
    EXPECT_THAT(error.what(), HasSubstr((temp / "colmap.log").string()));
  }
  EXPECT_TRUE(std::filesystem::exists(temp / "colmap.log"));
}

}  // namespace
}  // namespace hscloc
