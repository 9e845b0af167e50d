#include "util/subprocess.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

TEST(Subprocess, FindsProgramsOnPathOrByTheirPath) {
  const auto sh = FindExecutable("sh");
  ASSERT_TRUE(sh.has_value());
  EXPECT_TRUE(sh->is_absolute() || sh->string().find('/') != std::string::npos);
  EXPECT_EQ(FindExecutable(sh->string()), sh);
  EXPECT_FALSE(FindExecutable("hscloc-no-such-program").has_value());
  EXPECT_FALSE(FindExecutable("/nowhere/sh").has_value());
  EXPECT_FALSE(FindExecutable("").has_value());
}

TEST(Subprocess, RunsWithoutAShellAndKeepsItsOutput) {
  testing::TempDir temp;
  const std::string sh = FindExecutable("sh")->string();
  const auto log = temp / "run.log";
  // The argument with spaces and quotes reaches the program as one argument, unexpanded.
  EXPECT_EQ(RunProcess({sh, "-c", "echo \"$0\"; echo to-stderr >&2; exit 3", "a 'b' $HOME"}, log),
            3);
  EXPECT_EQ(LastLines(log, 5), "a 'b' $HOME\nto-stderr\n");
  EXPECT_EQ(LastLines(log, 1), "to-stderr\n");
  EXPECT_EQ(RunProcess({sh, "-c", "kill -9 $$"}, log), 128 + 9);
  EXPECT_EQ(RunProcess({"/nowhere/program"}, log), 127);
  EXPECT_THROW(RunProcess({sh, "-c", "true"}, temp / "missing" / "run.log"), std::runtime_error);
  EXPECT_EQ(LastLines(temp / "absent.log", 3), "");
}

}  // namespace
}  // namespace hscloc
