// The command-line tool end to end on the trained small city of the test fixture: localize a
// query list offline, resume an interrupted run, evaluate the submission; feature extraction from
// real photos.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "map/map_bundle.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "tests/hscloc_process.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::ReadText;
using testing::RunHscloc;

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto dir = testing::TrainedSmallCityDir();
    if (!dir) {
      GTEST_SKIP() << "the trained small city is missing: run the tests through ctest, whose "
                      "fixture.trained_small_city builds it";
    }
    city_ = *dir / "city";
    map_ = *dir / "map";
  }
  std::string DayList() const {
    return (city_ / "queries" / "day_time_queries_with_intrinsics.txt").string();
  }
  std::string NightList() const {
    return (city_ / "queries" / "night_time_queries_with_intrinsics.txt").string();
  }
  std::string Features() const { return (city_ / "features.h5").string(); }
  std::string GroundTruth() const { return (city_ / "queries_gt.txt").string(); }
  std::string Map() const { return map_.string(); }
  std::string Temp(const std::string& name) const { return (temp_ / name).string(); }

  fs::path city_;
  fs::path map_;
  testing::TempDir temp_;
};

TEST_F(CliTest, LocalizeResumeAndEvaluate) {
  // A first run over the day queries only, then a resumed run over day and night: the day lines
  // stay, the night ones are added, and a half-written line from an interruption is dropped.
  const std::string submission = Temp("out/submission.txt");
  ASSERT_EQ(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {}", Map(),
                                  DayList(), Features(), submission),
                      temp_ / "day.log"),
            0)
      << ReadText(temp_ / "day.log");
  EXPECT_THAT(ReadText(temp_ / "day.log"), HasSubstr("localized"));
  const std::vector<NamedPose> day = ReadPoses(submission);
  ASSERT_EQ(day.size(), ReadQueryList(DayList()).size());
  for (const NamedPose& pose : day) EXPECT_EQ(pose.name.find('/'), std::string::npos);
  std::ofstream(submission, std::ios::app) << "day_00049.jpg 0.1 0.2";  // interrupted mid-line

  ASSERT_EQ(
      RunHscloc(fmt::format("localize --map {} --queries {} --queries {} --features {} --out {} "
                            "--resume",
                            Map(), DayList(), NightList(), Features(), submission),
                temp_ / "resume.log"),
      0)
      << ReadText(temp_ / "resume.log");
  EXPECT_THAT(ReadText(temp_ / "resume.log"), HasSubstr("resuming: 50 of 100 queries"));
  const std::vector<NamedPose> all = ReadPoses(submission);
  ASSERT_EQ(all.size(), 100u);
  for (size_t i = 0; i < day.size(); ++i) {
    EXPECT_EQ(all[i].name, day[i].name);
    EXPECT_EQ(all[i].cam_from_world.translation, day[i].cam_from_world.translation);
  }

  const std::string plot = Temp("errors.svg");
  ASSERT_EQ(
      RunHscloc(fmt::format("eval --gt {} --results {} --conditions day:{},night:{} --plot {}",
                            GroundTruth(), submission, DayList(), NightList(), plot),
                temp_ / "eval.log"),
      0)
      << ReadText(temp_ / "eval.log");
  const std::string table = ReadText(temp_ / "eval.log");
  std::cout << table;
  EXPECT_THAT(table, HasSubstr("(0.25 m, 2 deg)"));
  EXPECT_THAT(table, HasSubstr("day"));
  EXPECT_THAT(table, HasSubstr("night"));
  EXPECT_THAT(ReadText(plot), HasSubstr("<svg"));
  // Day queries of the small city: at least 90% within (0.25 m, 2 deg).
  std::istringstream lines(table);
  std::string line;
  bool found_day = false;
  while (std::getline(lines, line)) {
    if (line.rfind("day", 0) != 0) continue;
    found_day = true;
    std::istringstream fields(line);
    std::string condition;
    int queries = 0;
    double fine = 0;
    fields >> condition >> queries >> fine;
    EXPECT_EQ(queries, 50);
    EXPECT_GE(fine, 90.0) << line;
  }
  EXPECT_TRUE(found_day);
}

// The server path (hscloc serve + hscloc-client batch, float32 descriptors, the global options
// after the subcommand) writes the same submission as the offline batch.
TEST_F(CliTest, ClientBatchThroughTheServerEqualsOfflineLocalize) {
  const std::string offline = Temp("offline.txt");
  ASSERT_EQ(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {}", Map(),
                                  NightList(), Features(), offline),
                      temp_ / "offline.log"),
            0);
  testing::HsclocProcess server({"serve", "--map", Map(), "--bind", "tcp://127.0.0.1:0",
                                 "--admin-bind", "tcp://127.0.0.1:0", "--workers", "2"},
                                temp_ / "serve.log");
  const std::string endpoint = server.WaitForLine("listening on ");
  ASSERT_FALSE(endpoint.empty()) << server.Log();
  const std::string served = Temp("served.txt");
  const int status = testing::RunCommand(
      fmt::format("{} batch --server {} --float32 --queries {} --features {} --out {} --inflight 4",
                  HSCLOC_CLIENT_BINARY, endpoint, NightList(), Features(), served),
      Temp("client.log"));
  const int server_status = server.Terminate();
  ASSERT_EQ(status, 0) << ReadText(temp_ / "client.log");
  EXPECT_EQ(server_status, 0) << server.Log();
  // Same lines; the client writes them in completion order.
  std::map<std::string, std::string> expected;
  for (const NamedPose& pose : ReadPoses(offline)) {
    expected[pose.name] = FormatPoseLine(pose.name, pose.cam_from_world);
  }
  const std::vector<NamedPose> actual = ReadPoses(served);
  ASSERT_EQ(actual.size(), expected.size());
  for (const NamedPose& pose : actual) {
    EXPECT_EQ(FormatPoseLine(pose.name, pose.cam_from_world), expected[pose.name]);
  }
}

// hscloc-client's global options are read on either side of the subcommand: the timeout error
// names the endpoint and the timeout given after it.
TEST(HsclocCliTest, LogLevelWorksOnEitherSideOfTheSubcommand) {
  testing::TempDir temp;
  const fs::path log = temp.path() / "inspect.log";
  for (const std::string& arguments : {std::string("--log-level bogus inspect /no/such/map"),
                                       std::string("inspect /no/such/map --log-level bogus")}) {
    EXPECT_EQ(RunHscloc(arguments, log), 2) << arguments;
    EXPECT_THAT(ReadText(log), HasSubstr("unknown log level 'bogus'")) << arguments;
  }
  // A known level after the subcommand is taken: the command runs (and names the missing map).
  EXPECT_EQ(RunHscloc("inspect /no/such/map --log-level warn", log), 2);
  EXPECT_THAT(ReadText(log), HasSubstr("/no/such/map"));
  EXPECT_THAT(ReadText(log), ::testing::Not(HasSubstr("log level")));
}

TEST(ClientCliTest, GlobalOptionsWorkOnEitherSideOfTheSubcommand) {
  testing::TempDir temp;
  const fs::path log = temp.path() / "health.log";
  EXPECT_EQ(testing::RunCommand(fmt::format("{} --retries 0 health --server tcp://127.0.0.1:1 "
                                            "--timeout-ms 100",
                                            HSCLOC_CLIENT_BINARY),
                                log.string()),
            1)
      << ReadText(log);
  // Both options reached the client: its whole bound, (0 + 1) x 100 ms, tried on the one server.
  EXPECT_THAT(ReadText(log), HasSubstr("no reply within 100 ms after"));
  EXPECT_THAT(ReadText(log), HasSubstr("tcp://127.0.0.1:1 refused"));
  EXPECT_NE(testing::RunCommand(fmt::format("{} health --no-such-option", HSCLOC_CLIENT_BINARY),
                                log.string()),
            0);
  EXPECT_THAT(ReadText(log), HasSubstr("--no-such-option"));
}

TEST(ClientCliTest, QueryWithABadXFeatModelNamesIt) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund/images");
  testing::TempDir temp;
  const fs::path model = temp / "broken.onnx";
  std::ofstream(model) << "not a model";
  const fs::path log = temp / "query.log";
  EXPECT_EQ(testing::RunCommand(
                fmt::format("{} query --image {} --feature xfeat --xfeat-model {} --camera "
                            "'PINHOLE 640 480 500 500 320 240' --server tcp://127.0.0.1:1",
                            HSCLOC_CLIENT_BINARY, (lund / "01.jpg").string(), model.string()),
                log.string()),
            2)
      << ReadText(log);
  EXPECT_THAT(ReadText(log), HasSubstr(model.string() + " is not a valid ONNX model"));
}

TEST(ExtractCliTest, WritesHlocFeaturesAndResumes) {
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund/images");
  HSCLOC_REQUIRE_REAL_DATA(weights, "weights/xfeat");
  testing::TempDir temp;
  const fs::path list = temp / "list.txt";
  std::ofstream(list) << "01.jpg\n02.jpg\n";
  const fs::path out = temp / "features.h5";
  const std::string extract =
      fmt::format("extract --images {} --list {} --feature xfeat --out {} --xfeat-model {}",
                  lund.string(), list.string(), out.string(), (weights / "xfeat.onnx").string());
  ASSERT_EQ(RunHscloc(extract, temp / "first.log"), 0) << ReadText(temp / "first.log");
  EXPECT_THAT(ReadText(temp / "first.log"), HasSubstr("2 extracted"));
  {
    // Closed before the second run: HDF5 locks an open file.
    const auto reader = OpenFeatureReader(out);
    EXPECT_THAT(reader->ImageNames(), ::testing::ElementsAre("01.jpg", "02.jpg"));
    const ImageFeatures features = reader->Read("01.jpg");
    EXPECT_EQ(features.NumKeypoints(), 2048);
    EXPECT_EQ(features.Dimension(), 64);
    EXPECT_EQ(features.scores.size(), 2048);
  }

  ASSERT_EQ(RunHscloc(extract, temp / "second.log"), 0) << ReadText(temp / "second.log");
  EXPECT_THAT(ReadText(temp / "second.log"), HasSubstr("0 extracted"));
  EXPECT_THAT(ReadText(temp / "second.log"), HasSubstr("2 already there"));

  EXPECT_EQ(RunHscloc(fmt::format("extract --images {} --out {}", (temp / "nowhere").string(),
                                  out.string()),
                      temp / "bad.log"),
            2);
  EXPECT_THAT(ReadText(temp / "bad.log"), HasSubstr("nowhere does not exist"));
}

// Triangulation's bad inputs stop it before any matching, with the input named and exit status 2.
TEST(TriangulateCliTest, BadInputsFailWithAClearMessage) {
  HSCLOC_REQUIRE_REAL_DATA(fountain, "fountain-P11");
  HSCLOC_REQUIRE_REAL_DATA(lund, "lund");
  testing::TempDir temp;
  const auto triangulate = [&](const fs::path& model, const fs::path& features,
                               const std::string& extra, const fs::path& log) {
    return RunHscloc(fmt::format("triangulate --model {} --features {} --out {} {}", model.string(),
                                 features.string(), (temp / "out").string(), extra),
                     log);
  };
  EXPECT_NE(triangulate(temp / "nowhere", fountain / "database.db", "", temp / "model.log"), 0);
  EXPECT_THAT(ReadText(temp / "model.log"), HasSubstr("nowhere"));
  EXPECT_EQ(triangulate(fountain / "map", lund / "database.db", "", temp / "features.log"), 2);
  EXPECT_THAT(ReadText(temp / "features.log"),
              HasSubstr("has no features for 9 of the model's 9 images: 0000.jpg, 0001.jpg"));
  EXPECT_EQ(triangulate(fountain / "map", fountain / "database.db", "--colmap /nowhere/colmap",
                        temp / "colmap.log"),
            2);
  EXPECT_THAT(ReadText(temp / "colmap.log"), HasSubstr("'/nowhere/colmap' was not found"));
}

// Ctrl-C during a long training keeps what was learned: the network so far goes into the bundle
// and the checkpoint, and the command says so and exits 0.
TEST_F(CliTest, InterruptedTrainingKeepsTheNetworkSoFar) {
  const fs::path map = temp_ / "map";
  fs::copy(map_, map, fs::copy_options::recursive);
  const fs::path log = temp_ / "train.log";
  testing::HsclocProcess train({"train", "--map", map.string(), "--iterations", "1000000",
                                "--checkpoint", Temp("train.ckpt"), "--threads", "1"},
                               log);
  ASSERT_FALSE(train.WaitForLine("loaded ").empty()) << train.Log();
  std::this_thread::sleep_for(std::chrono::seconds(3));
  ASSERT_EQ(train.Terminate(SIGINT), 0) << train.Log();
  const std::string output = ReadText(log);
  const size_t at = output.find("interrupted after ");
  ASSERT_NE(at, std::string::npos) << output;
  const int64_t iterations = std::stoll(output.substr(at + 18));
  EXPECT_GT(iterations, 0);
  EXPECT_LT(iterations, 1000000);
  EXPECT_TRUE(fs::exists(Temp("train.ckpt")));
  const MapBundle bundle = MapBundle::Open(map);
  EXPECT_EQ(bundle.metadata()["network"]["training"]["iterations"], iterations);
}

// `--matcher auto` is the default and may also be named: localize and serve accept it, and the
// named and the implied default give the same submission; an unknown matcher is refused by name.
TEST_F(CliTest, MatcherAutoMayBeNamed) {
  const std::string implied = Temp("implied.txt");
  const std::string named = Temp("named.txt");
  ASSERT_EQ(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {}", Map(),
                                  NightList(), Features(), implied),
                      temp_ / "implied.log"),
            0)
      << ReadText(temp_ / "implied.log");
  ASSERT_EQ(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {} "
                                  "--matcher auto",
                                  Map(), NightList(), Features(), named),
                      temp_ / "named.log"),
            0)
      << ReadText(temp_ / "named.log");
  EXPECT_THAT(ReadText(temp_ / "named.log"), HasSubstr("matcher auto: "));
  // Queries run in parallel and are written as they finish: compare the lines, not their order.
  const auto sorted_lines = [](const std::string& path) {
    std::istringstream text(ReadText(path));
    std::vector<std::string> lines;
    for (std::string line; std::getline(text, line);) lines.push_back(line);
    std::sort(lines.begin(), lines.end());
    return lines;
  };
  EXPECT_EQ(sorted_lines(named), sorted_lines(implied));
  EXPECT_EQ(sorted_lines(named).size(), ReadQueryList(NightList()).size());

  EXPECT_NE(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {} "
                                  "--matcher nearest",
                                  Map(), NightList(), Features(), Temp("unknown.txt")),
                      temp_ / "unknown.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "unknown.log"), HasSubstr("--matcher: nearest not in"));

  testing::HsclocProcess server({"serve", "--map", Map(), "--bind", "tcp://127.0.0.1:0",
                                 "--admin-bind", "tcp://127.0.0.1:0", "--matcher", "auto"},
                                temp_ / "serve.log");
  EXPECT_FALSE(server.WaitForLine("listening on ").empty()) << server.Log();
  EXPECT_THAT(server.Log(), HasSubstr("matcher auto: "));
}

TEST_F(CliTest, BadInputsFailWithAClearMessage) {
  const std::string bad_list = Temp("bad.txt");
  std::ofstream(bad_list) << "query/day/day_00000.jpg NO_SUCH_MODEL 10 10 1 2 3\n";
  EXPECT_NE(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {}", Map(),
                                  bad_list, Features(), Temp("s.txt")),
                      temp_ / "bad.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "bad.log"), HasSubstr("bad.txt:1"));

  const std::string unknown = Temp("unknown.txt");
  std::ofstream(unknown) << "nowhere.jpg PINHOLE 640 480 500 500 320 240\n";
  EXPECT_NE(RunHscloc(fmt::format("localize --map {} --queries {} --features {} --out {}", Map(),
                                  unknown, Features(), Temp("s.txt")),
                      temp_ / "unknown.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "unknown.log"), HasSubstr("no features for query 'nowhere.jpg'"));

  const std::string results = Temp("results.txt");
  std::ofstream(results) << "stranger.jpg 1 0 0 0 0 0 0\n";
  EXPECT_NE(RunHscloc(fmt::format("eval --gt {} --results {}", GroundTruth(), results),
                      temp_ / "eval.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "eval.log"), HasSubstr("'stranger.jpg' is not a query"));

  EXPECT_NE(RunHscloc(fmt::format("train --map {} --output shortcut --node-output-dim 8", Map()),
                      temp_ / "train.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "train.log"),
              HasSubstr("--output shortcut scores points at the descriptor's width"));

  // The last round's options reach the server too, checked as the batch's are.
  EXPECT_NE(RunHscloc(fmt::format("serve --map {} --bind tcp://127.0.0.1:0 "
                                  "--nearest-point-widened-candidates -1",
                                  Map()),
                      temp_ / "serve_options.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "serve_options.log"),
              HasSubstr("--nearest-point-widened-candidates: Value -1 not in range"));

  // A folder that is not a real set, a bank that is not one, a real appearance without a bank.
  fs::create_directories(Temp("not-a-set"));
  EXPECT_NE(RunHscloc(fmt::format("bank --set {} --out {}", Temp("not-a-set"), Temp("b.bank")),
                      temp_ / "bank.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "bank.log"), HasSubstr("needs images/ (photos) and map/"));
  EXPECT_FALSE(fs::exists(Temp("b.bank")));
  std::ofstream(Temp("fake.bank")) << "nothing like a bank";
  EXPECT_NE(RunHscloc(fmt::format("synth --preset tiny --appearance real --bank {} --out {}",
                                  Temp("fake.bank"), Temp("fake-city")),
                      temp_ / "synth.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "synth.log"), HasSubstr("is not a descriptor bank"));
  EXPECT_NE(
      RunHscloc(fmt::format("synth --preset tiny --appearance real --out {}", Temp("no-bank-city")),
                temp_ / "synth2.log"),
      0);
  EXPECT_THAT(ReadText(temp_ / "synth2.log"), HasSubstr("--appearance real needs --bank"));

  // The demo's real appearance from a folder that is no photo set, and options of the synthetic
  // city given to the real one: each refused before any work, nothing written.
  EXPECT_EQ(
      RunHscloc(fmt::format("demo --bank-set {} --out {}", Temp("not-a-set"), Temp("demo-out")),
                temp_ / "demo.log"),
      2);
  EXPECT_THAT(
      ReadText(temp_ / "demo.log"),
      HasSubstr(fmt::format("photo set {}, which has no images/ and map/", Temp("not-a-set"))));
  EXPECT_FALSE(fs::exists(Temp("demo-out/bank")));
  EXPECT_NE(RunHscloc(fmt::format("demo --real --appearance random --out {}", Temp("demo-out")),
                      temp_ / "demo2.log"),
            0);
  EXPECT_THAT(ReadText(temp_ / "demo2.log"), HasSubstr("are the synthetic city's, not --real's"));
}

}  // namespace
}  // namespace hscloc
