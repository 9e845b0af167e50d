// The service over real loopback sockets, against the trained small city of the test fixture.
#include "server/localization_service.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <set>
#include <thread>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "client/localization_client.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/loopback_testing.h"
#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

struct Query {
  std::string name;
  Camera camera;
  ImageFeatures features;
};

wire::LocalizeRequest RequestOf(const Query& query, bool float16 = false,
                                int64_t max_keypoints = -1) {
  const int64_t n = max_keypoints < 0 ? query.features.NumKeypoints()
                                      : std::min(max_keypoints, query.features.NumKeypoints());
  return QueryToWire({query.name, query.camera, query.features.keypoints.topRows(n),
                      query.features.descriptors.topRows(n), std::nullopt},
                     float16);
}

class LocalizationServiceTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const auto dir = testing::TrainedSmallCityDir();
    if (!dir) return;
    dir_ = new fs::path(*dir);
    queries_ = new std::vector<Query>();
    const auto features = OpenH5Features(*dir / "city" / "features.h5");
    for (const QueryWithIntrinsics& entry :
         ReadQueryList(*dir / "city" / "queries" / "day_time_queries_with_intrinsics.txt")) {
      queries_->push_back({entry.name, entry.camera, features->Read(entry.name)});
      if (queries_->size() == 12) break;
    }
  }
  static void TearDownTestSuite() {
    delete dir_;
    delete queries_;
    dir_ = nullptr;
  }
  void SetUp() override {
    if (dir_ == nullptr) {
      GTEST_SKIP() << "the trained small city is missing: run the tests through ctest, whose "
                      "fixture.trained_small_city builds it";
    }
  }
  static fs::path MapDir() { return *dir_ / "map"; }
  static const std::vector<Query>& Queries() { return *queries_; }

  static ServiceOptions LoopbackOptions() {
    ServiceOptions options;
    options.bind = "tcp://127.0.0.1:0";
    options.admin_bind = "tcp://127.0.0.1:0";
    options.workers = 2;
    return options;
  }
  static ClientOptions ClientFor(const std::string& endpoint) {
    ClientOptions options;
    options.servers = {endpoint};
    options.timeout_ms = 60000;
    options.retries = 0;
    return options;
  }

  testing::TempDir temp_;

 private:
  static fs::path* dir_;
  static std::vector<Query>* queries_;
};
fs::path* LocalizationServiceTest::dir_ = nullptr;
std::vector<Query>* LocalizationServiceTest::queries_ = nullptr;

TEST_F(LocalizationServiceTest, AnswersAsTheInProcessLocalizer) {
  LocalizationService service(MapDir(), LoopbackOptions());
  const std::string endpoint = service.Start();
  const Localizer localizer = Localizer::FromBundle(MapDir());
  LocalizationClient client(ClientFor(endpoint));
  const wire::InfoResponse info = client.Info();
  EXPECT_EQ(info.descriptor_dim(), 256u);
  EXPECT_EQ(info.num_images(), localizer.map().scene().NumImages());
  EXPECT_EQ(info.map_id(), MapIdOf(MapDir()));
  EXPECT_EQ(client.Health().status(), wire::OK);
  for (size_t i = 0; i < 4; ++i) {
    const Query& query = Queries()[i];
    const wire::LocalizeResponse response = client.Localize(RequestOf(query));
    const PoseResult expected = localizer.Localize(
        {query.name, query.camera, query.features.keypoints, query.features.descriptors, {}});
    ASSERT_EQ(response.status(), expected.success ? wire::OK : wire::NOT_LOCALIZED)
        << response.error_message();
    EXPECT_EQ(response.request_id(), query.name);
    EXPECT_EQ(response.num_inliers(), static_cast<uint32_t>(expected.num_inliers));
    EXPECT_EQ(response.cam_from_world().tx(), expected.cam_from_world.translation.x());
    EXPECT_EQ(response.cam_from_world().qw(), expected.cam_from_world.rotation.w());
    EXPECT_EQ(response.candidates_size(), static_cast<int>(expected.candidates.size()));
    EXPECT_GT(response.timings().server_ms(), response.timings().total_ms());
  }
  // float16 descriptors localize too.
  const wire::LocalizeResponse half = client.Localize(RequestOf(Queries()[0], true));
  EXPECT_EQ(half.status(), wire::OK);
}

TEST_F(LocalizationServiceTest, MetricsCountTheRepliesAndTimeTheStages) {
  HSCLOC_REQUIRE_PROMTOOL(promtool);
  ServiceOptions options = LoopbackOptions();
  options.metrics_bind = "127.0.0.1:0";
  LocalizationService service(MapDir(), options);
  const std::string endpoint = service.Start();
  LocalizationClient client(ClientFor(endpoint));
  EXPECT_EQ(client.Health().status(), wire::OK);
  int localized = 0;
  for (int i = 0; i < 3; ++i) {
    wire::LocalizeRequest request = RequestOf(Queries()[i], true, 200);
    request.mutable_options()->set_top_k(2);
    localized += client.Localize(request).status() == wire::OK;
  }
  wire::LocalizeRequest invalid = RequestOf(Queries()[0], true, 200);
  invalid.set_descriptor_dim(128);
  EXPECT_EQ(client.Localize(invalid).status(), wire::INVALID_REQUEST);

  const std::string text = testing::HttpGet(service.metrics_url());
  const auto sample = [&](const std::string& series) {
    return testing::MetricSample(text, series).value_or(0);
  };
  EXPECT_EQ(sample(R"(hscloc_requests_total{kind="localize",status="OK"})"), localized);
  EXPECT_EQ(sample(R"(hscloc_requests_total{kind="localize",status="NOT_LOCALIZED"})"),
            3 - localized);
  EXPECT_EQ(sample(R"(hscloc_requests_total{kind="localize",status="INVALID_REQUEST"})"), 1);
  EXPECT_EQ(sample(R"(hscloc_requests_total{kind="health",status="OK"})"), 1);
  // The stages of the three requests the Localizer ran, none of the refused one.
  for (const std::string stage : {"queue", "retrieval", "match", "pose", "server"}) {
    EXPECT_EQ(sample(R"(hscloc_localize_duration_seconds_count{stage=")" + stage + R"("})"), 3)
        << stage;
  }
  EXPECT_GT(sample(R"(hscloc_localize_duration_seconds_sum{stage="match"})"), 0);
  EXPECT_EQ(sample(fmt::format(R"(hscloc_map_info{{map_id="{}"}})", MapIdOf(MapDir()))), 1);
  EXPECT_EQ(sample(R"(hscloc_map_loads_total{outcome="success"})"), 1);
  EXPECT_GT(sample("hscloc_map_load_seconds"), 0);
  EXPECT_EQ(sample("hscloc_queue_depth"), 0);
  EXPECT_EQ(sample("hscloc_workers"), 2);
  testing::TempDir dir;
  std::ofstream(dir / "metrics.txt") << text;
  EXPECT_EQ(testing::RunCommand(promtool + " check metrics < " + (dir / "metrics.txt").string()),
            0);
}

TEST_F(LocalizationServiceTest, EightConcurrentClientsAreAllAnswered) {
  LocalizationService service(MapDir(), LoopbackOptions());
  const std::string endpoint = service.Start();
  std::atomic<int> ok{0};
  std::vector<std::thread> clients;
  for (int c = 0; c < 8; ++c) {
    clients.emplace_back([&, c] {
      LocalizationClient client(ClientFor(endpoint));
      for (int r = 0; r < 50; ++r) {
        // Cheap requests (100 keypoints, one candidate) keep 400 of them quick.
        wire::LocalizeRequest request = RequestOf(Queries()[(c + r) % Queries().size()], true, 100);
        request.set_request_id(fmt::format("{}-{}", c, r));
        request.mutable_options()->set_top_k(1);
        const wire::LocalizeResponse response = client.Localize(request);
        if (response.request_id() == request.request_id() &&
            (response.status() == wire::OK || response.status() == wire::NOT_LOCALIZED)) {
          ++ok;
        }
      }
    });
  }
  for (std::thread& client : clients) client.join();
  EXPECT_EQ(ok.load(), 400);
  EXPECT_GE(service.requests_answered(), 400u);
}

TEST_F(LocalizationServiceTest, MalformedRequestsGetInvalidRequestAndServingGoesOn) {
  LocalizationService service(MapDir(), LoopbackOptions());
  const std::string endpoint = service.Start();
  LocalizationClient client(ClientFor(endpoint));
  const wire::LocalizeRequest good = RequestOf(Queries()[0], true);
  const auto expect_invalid = [&](wire::LocalizeRequest request, const std::string& message) {
    const wire::LocalizeResponse response = client.Localize(request);
    EXPECT_EQ(response.status(), wire::INVALID_REQUEST) << message;
    EXPECT_THAT(response.error_message(), HasSubstr(message));
  };
  wire::LocalizeRequest request = good;
  request.set_descriptor_dim(128);
  expect_invalid(request, "descriptors hold");
  request = good;
  request = RequestOf(Queries()[0], false);
  {
    std::string descriptors = request.descriptors();
    const float nan = std::nanf("");
    std::memcpy(descriptors.data() + 40, &nan, 4);
    request.set_descriptors(descriptors);
  }
  expect_invalid(request, "non-finite descriptor");
  request = good;
  request.mutable_camera()->set_model("FISHEYE_9000");
  expect_invalid(request, "camera");
  request = good;
  request.mutable_camera()->add_params(1.0);
  expect_invalid(request, "camera");
  request = good;
  {
    std::string keypoints = request.keypoints();
    const float outside = 1e6f;
    std::memcpy(keypoints.data(), &outside, 4);
    request.set_keypoints(keypoints);
  }
  expect_invalid(request, "outside");
  request = good;
  request.set_num_keypoints(1000000);
  request.set_keypoints(std::string(8000000, '\0'));
  request.set_descriptor_dim(1);
  request.set_descriptors(std::string(4000000, '\0'));
  request.set_descriptor_type(wire::DESCRIPTOR_FLOAT32);
  expect_invalid(request, "exceeds the server's limit");
  request = good;
  request.mutable_options()->set_top_k(0);
  expect_invalid(request, "top_k");
  request = good;
  request.set_map_id("another-city");
  expect_invalid(request, "another-city");

  // Envelope-level faults, over a raw socket: fuzzed bytes, wrong version, no kind.
  zmq::context_t context(1);
  zmq::socket_t raw(context, zmq::socket_type::dealer);
  raw.set(zmq::sockopt::rcvtimeo, 30000);
  raw.connect(endpoint);
  const auto raw_call = [&](const std::string& payload) {
    raw.send(zmq::buffer(std::string("id")), zmq::send_flags::sndmore);
    raw.send(zmq::buffer(payload), zmq::send_flags::none);
    std::vector<zmq::message_t> frames;
    EXPECT_TRUE(zmq::recv_multipart(raw, std::back_inserter(frames)));
    wire::Response response;
    EXPECT_EQ(frames.size(), 2u);
    EXPECT_TRUE(response.ParseFromArray(frames.back().data(), frames.back().size()));
    return response;
  };
  Random random(7);
  for (int trial = 0; trial < 20; ++trial) {
    std::string fuzz = good.SerializeAsString().substr(0, 64);
    for (char& byte : fuzz) {
      if (random.Bernoulli(0.3)) byte = static_cast<char>(random.UniformInt(256));
    }
    const wire::Response response = raw_call(fuzz);
    EXPECT_NE(response.status(), wire::OK);
    if (response.has_localize()) {
      EXPECT_NE(response.localize().status(), wire::OK);
    }
  }
  wire::Request old_version;
  old_version.set_protocol_version(0);
  old_version.mutable_health();
  wire::Response response = raw_call(old_version.SerializeAsString());
  EXPECT_EQ(response.status(), wire::INVALID_REQUEST);
  EXPECT_THAT(response.error_message(), HasSubstr("protocol version 0"));
  wire::Request no_kind;
  no_kind.set_protocol_version(kProtocolVersion);
  EXPECT_EQ(raw_call(no_kind.SerializeAsString()).status(), wire::INVALID_REQUEST);

  EXPECT_EQ(client.Health().status(), wire::OK);
  EXPECT_EQ(client.Localize(good).status(), wire::OK);
}

TEST_F(LocalizationServiceTest, FullQueueAnswersOverloaded) {
  ServiceOptions options = LoopbackOptions();
  options.workers = 1;
  options.max_queue = 1;
  LocalizationService service(MapDir(), options);
  const std::string endpoint = service.Start();
  zmq::context_t context(1);
  zmq::socket_t dealer(context, zmq::socket_type::dealer);
  dealer.set(zmq::sockopt::rcvtimeo, 60000);
  dealer.connect(endpoint);
  wire::Request request;
  request.set_protocol_version(kProtocolVersion);
  *request.mutable_localize() = RequestOf(Queries()[0], true);
  const std::string payload = request.SerializeAsString();
  constexpr int kRequests = 12;
  for (int i = 0; i < kRequests; ++i) {
    dealer.send(zmq::buffer(std::to_string(i)), zmq::send_flags::sndmore);
    dealer.send(zmq::buffer(payload), zmq::send_flags::none);
  }
  std::map<wire::Status, int> statuses;
  std::set<std::string> answered;
  for (int i = 0; i < kRequests; ++i) {
    std::vector<zmq::message_t> frames;
    ASSERT_TRUE(zmq::recv_multipart(dealer, std::back_inserter(frames)));
    answered.insert(frames[0].to_string());
    wire::Response response;
    ASSERT_TRUE(response.ParseFromArray(frames[1].data(), frames[1].size()));
    ++statuses[response.localize().status()];
  }
  EXPECT_EQ(answered.size(), static_cast<size_t>(kRequests));  // every request, exactly once
  EXPECT_GE(statuses[wire::OVERLOADED], 1);
  EXPECT_GE(statuses[wire::OK], 1);
}

TEST_F(LocalizationServiceTest, StopDrainsAcceptedRequestsAndRefusesLaterOnes) {
  auto service = std::make_unique<LocalizationService>(MapDir(), LoopbackOptions());
  const std::string endpoint = service->Start();
  zmq::context_t context(1);
  zmq::socket_t dealer(context, zmq::socket_type::dealer);
  dealer.set(zmq::sockopt::rcvtimeo, 60000);
  dealer.connect(endpoint);
  const auto send = [&](const std::string& id, const wire::Request& request) {
    dealer.send(zmq::buffer(id), zmq::send_flags::sndmore);
    dealer.send(zmq::buffer(request.SerializeAsString()), zmq::send_flags::none);
  };
  wire::Request localize;
  localize.set_protocol_version(kProtocolVersion);
  *localize.mutable_localize() = RequestOf(Queries()[1], true);
  wire::Request health;
  health.set_protocol_version(kProtocolVersion);
  health.mutable_health();
  for (int i = 0; i < 4; ++i) send(std::to_string(i), localize);
  // One connection's messages are read in order: once the health reply is back, the server has
  // accepted the four requests before it.
  send("health", health);
  std::map<std::string, wire::Status> statuses;
  const auto receive = [&] {
    std::vector<zmq::message_t> frames;
    if (!zmq::recv_multipart(dealer, std::back_inserter(frames))) return false;
    wire::Response response;
    EXPECT_TRUE(response.ParseFromArray(frames[1].data(), frames[1].size()));
    statuses[frames[0].to_string()] =
        response.has_localize() ? response.localize().status() : response.status();
    return true;
  };
  while (!statuses.count("health")) ASSERT_TRUE(receive());
  std::thread stopper([&] { service->Stop(); });
  // A health probe and a localize request back to back, until a probe finds the server stopping.
  // One connection's messages are read in order and a stopping server never serves again, so the
  // request right after a refused probe must be refused too (UNAVAILABLE), not dropped or served.
  dealer.set(zmq::sockopt::rcvtimeo, 10000);
  std::string refused_probe;
  for (int pair = 0; refused_probe.empty() && pair < 10000; ++pair) {
    const std::string probe = "probe" + std::to_string(pair);
    send(probe, health);
    send("late" + std::to_string(pair), localize);
    while (!statuses.count(probe)) ASSERT_TRUE(receive()) << probe;
    if (statuses[probe] == wire::UNAVAILABLE) refused_probe = probe;
  }
  ASSERT_FALSE(refused_probe.empty()) << "no probe saw the server stopping";
  const std::string late = "late" + refused_probe.substr(5);
  while (!statuses.count(late)) ASSERT_TRUE(receive()) << late;
  // The four accepted requests were answered before the server stopped; their replies may still
  // wait in this socket.
  for (int i = 0; i < 4; ++i) {
    while (!statuses.count(std::to_string(i))) ASSERT_TRUE(receive()) << i;
  }
  stopper.join();
  for (int i = 0; i < 4; ++i) EXPECT_EQ(statuses[std::to_string(i)], wire::OK) << i;
  EXPECT_EQ(statuses[late], wire::UNAVAILABLE);
}

// Copies the bundle (its files are small enough) so that it can be damaged.
fs::path CopyMap(const fs::path& from, const fs::path& to) {
  fs::copy(from, to, fs::copy_options::recursive);
  return to;
}

TEST_F(LocalizationServiceTest, CorruptMapOnReloadLeavesTheOldMapServing) {
  const fs::path map = CopyMap(MapDir(), temp_ / "map");
  LocalizationService service(map, LoopbackOptions());
  const std::string endpoint = service.Start();
  LocalizationClient client(ClientFor(endpoint));
  {
    std::fstream file(map / "label_tree.bin", std::ios::in | std::ios::out | std::ios::binary);
    file.seekp(100);
    file.put('\x5a');
  }
  LocalizationClient admin(ClientFor(service.admin_endpoint()));
  const wire::ReloadResponse failed = admin.Reload();
  EXPECT_EQ(failed.status(), wire::INTERNAL);
  EXPECT_THAT(failed.error_message(), HasSubstr("label_tree.bin"));
  EXPECT_EQ(client.Localize(RequestOf(Queries()[2], true)).status(), wire::OK);

  fs::copy_file(MapDir() / "label_tree.bin", map / "label_tree.bin",
                fs::copy_options::overwrite_existing);
  EXPECT_TRUE(service.Reload().success);
  EXPECT_EQ(client.Localize(RequestOf(Queries()[2], true)).status(), wire::OK);
}

TEST_F(LocalizationServiceTest, CurveRefusesClientsWithoutAnAllowedKey) {
  const CurveKeyPair server_keys = GenerateCurveKeyPair();
  const CurveKeyPair allowed = GenerateCurveKeyPair();
  ServiceOptions options = LoopbackOptions();
  options.curve_secret_key = server_keys.secret_key;
  options.curve_allowed_client_keys = {allowed.public_key};
  LocalizationService service(MapDir(), options);
  const std::string endpoint = service.Start();

  ClientOptions good = ClientFor(endpoint);
  good.curve_server_key = server_keys.public_key;
  good.curve_public_key = allowed.public_key;
  good.curve_secret_key = allowed.secret_key;
  EXPECT_EQ(LocalizationClient(good).Health().status(), wire::OK);

  ClientOptions stranger = ClientFor(endpoint);
  stranger.curve_server_key = server_keys.public_key;  // a fresh key pair is generated
  stranger.timeout_ms = 500;
  LocalizationClient refused(stranger);
  EXPECT_THROW(refused.Health(), ClientError);
  ClientOptions plain = ClientFor(endpoint);
  plain.timeout_ms = 500;
  LocalizationClient unencrypted(plain);
  EXPECT_THROW(unencrypted.Health(), ClientError);
}

}  // namespace
}  // namespace hscloc
