// The admin endpoint over real sockets: who may reload, how reloads coalesce, and what the
// process's own Health says while its map loads and while it has no broker.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <future>
#include <iostream>
#include <set>
#include <thread>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "server/loopback_testing.h"
#include "server/wire.h"
#include "util/parallel.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

using testing::HeldMap;
using testing::LoopbackServiceOptions;

LocalizationClient ClientFor(const std::string& endpoint) {
  return LocalizationClient(testing::PatientClientOptions(endpoint));
}

size_t ThreadsOfThisProcess() {
  size_t threads = 0;
  for ([[maybe_unused]] const auto& task : fs::directory_iterator("/proc/self/task")) ++threads;
  return threads;
}

TEST(AdminEndpointTest, ReloadIsDeniedOnThePublicEndpointAndAcceptedOnTheAdminOne) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  LocalizationService service(dir / "map", LoopbackServiceOptions());
  const std::string endpoint = service.Start();
  ASSERT_EQ(service.reloads_executed(), 1u);  // the first load

  const wire::ReloadResponse denied = ClientFor(endpoint).Reload();
  EXPECT_EQ(denied.status(), wire::PERMISSION_DENIED);
  EXPECT_THAT(denied.error_message(), HasSubstr("--admin-bind"));
  EXPECT_EQ(service.reloads_executed(), 1u);

  const wire::ReloadResponse reloaded = ClientFor(service.admin_endpoint()).Reload();
  EXPECT_EQ(reloaded.status(), wire::OK) << reloaded.error_message();
  EXPECT_EQ(reloaded.map_id(), MapIdOf(dir / "map"));
  EXPECT_EQ(service.reloads_executed(), 2u);
  // The admin endpoint answers the probes too.
  EXPECT_EQ(ClientFor(service.admin_endpoint()).Health().status(), wire::OK);
}

TEST(AdminEndpointTest, ABurstOfReloadsRunsAtMostTwoOnBoundedThreads) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  LocalizationService service(dir / "map", LoopbackServiceOptions());
  service.Start();
  const size_t threads_before = ThreadsOfThisProcess();
  const size_t loads_before = service.reloads_executed();

  zmq::context_t context(1);
  zmq::socket_t dealer(context, zmq::socket_type::dealer);
  dealer.set(zmq::sockopt::rcvtimeo, 60000);
  dealer.connect(service.admin_endpoint());
  wire::Request reload;
  reload.set_protocol_version(kProtocolVersion);
  reload.mutable_reload();
  const std::string payload = reload.SerializeAsString();
  constexpr int kReloads = 500;
  for (int i = 0; i < kReloads; ++i) {
    dealer.send(zmq::buffer(std::to_string(i)), zmq::send_flags::sndmore);
    dealer.send(zmq::buffer(payload), zmq::send_flags::none);
  }
  size_t most_threads = ThreadsOfThisProcess();
  std::set<std::string> answered;
  for (int i = 0; i < kReloads; ++i) {
    std::vector<zmq::message_t> frames;
    ASSERT_TRUE(zmq::recv_multipart(dealer, std::back_inserter(frames))) << i;
    wire::Response response;
    ASSERT_TRUE(response.ParseFromArray(frames[1].data(), frames[1].size()));
    EXPECT_EQ(response.reload().status(), wire::OK) << response.reload().error_message();
    answered.insert(frames[0].to_string());
    most_threads = std::max(most_threads, ThreadsOfThisProcess());
  }
  const size_t reloads = service.reloads_executed() - loads_before;
  std::cout << fmt::format(
      "{} reload requests: {} reloads executed, threads {} before, at most {}\n", kReloads, reloads,
      threads_before, most_threads);
  EXPECT_EQ(answered.size(), static_cast<size_t>(kReloads));
  EXPECT_GE(reloads, 1u);
  EXPECT_LE(reloads, 2u);
  // The reload's own thread and the loading's, one per core (the blobs are read in parallel),
  // however many requests came.
  EXPECT_LE(most_threads, threads_before + 2 + static_cast<size_t>(ResolveNumThreads(0)));
}

TEST(AdminEndpointTest, AnAdminCurveKeyMayReloadOnThePublicEndpoint) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  const CurveKeyPair server = GenerateCurveKeyPair();
  const CurveKeyPair client = GenerateCurveKeyPair();
  const CurveKeyPair admin = GenerateCurveKeyPair();
  ServiceOptions options = LoopbackServiceOptions();
  options.curve_secret_key = server.secret_key;
  options.curve_allowed_client_keys = {client.public_key};
  options.curve_admin_keys = {admin.public_key};
  LocalizationService service(dir / "map", options);
  const std::string endpoint = service.Start();
  const auto reload_as = [&](const CurveKeyPair& keys) {
    ClientOptions client_options = testing::PatientClientOptions(endpoint);
    client_options.curve_server_key = server.public_key;
    client_options.curve_secret_key = keys.secret_key;
    return LocalizationClient(client_options).Reload().status();
  };
  EXPECT_EQ(reload_as(client), wire::PERMISSION_DENIED);
  EXPECT_EQ(service.reloads_executed(), 1u);
  EXPECT_EQ(reload_as(admin), wire::OK);
  EXPECT_EQ(service.reloads_executed(), 2u);
}

// Health on `endpoint` until its status is `status` (or a minute has passed).
wire::HealthResponse HealthOnceItIs(const std::string& endpoint, wire::Status status) {
  LocalizationClient client = ClientFor(endpoint);
  wire::HealthResponse health = client.Health();
  for (int i = 0; i < 600 && health.status() != status; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    health = client.Health();
  }
  return health;
}

TEST(AdminEndpointTest, HealthSaysLoadingUntilTheMapIsVerified) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  testing::TempDir temp;
  HeldMap map(dir / "map", temp / "map");
  ServiceOptions options = LoopbackServiceOptions();
  options.bind = testing::IpcEndpoint("public");
  options.admin_bind = testing::IpcEndpoint("admin");
  LocalizationService service(map.dir(), options);
  auto started = std::async(std::launch::async, [&] { return service.Start(); });

  const wire::HealthResponse loading = ClientFor(options.admin_bind).Health();
  EXPECT_EQ(loading.status(), wire::LOADING);
  EXPECT_THAT(loading.reason(), HasSubstr("loading and verifying the map"));
  const wire::Response info = [&] {
    wire::Request request;
    request.mutable_info();
    return ClientFor(options.bind).Call(request);
  }();
  EXPECT_EQ(info.status(), wire::UNAVAILABLE);

  map.Release();
  started.get();
  EXPECT_EQ(ClientFor(options.admin_bind).Health().status(), wire::OK);
}

TEST(AdminEndpointTest, AWorkerWithoutABrokerIsAliveAndNotReadyAndSaysWhy) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  ServiceOptions options = LoopbackServiceOptions({"tcp://127.0.0.1:1"});  // no broker there
  LocalizationService service(dir / "map", options);
  service.Start();
  const wire::HealthResponse health = ClientFor(service.admin_endpoint()).Health();
  EXPECT_EQ(health.status(), wire::UNAVAILABLE);
  EXPECT_THAT(health.reason(), HasSubstr("no word yet from the broker at tcp://127.0.0.1:1"));
  EXPECT_EQ(health.map_id(), MapIdOf(dir / "map"));
}

TEST(AdminEndpointTest, AWorkerIsReadyOnlyOnceItsMapIsVerifiedAndItsBrokerAnswers) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  testing::TempDir temp;
  Broker broker(testing::LoopbackBrokerOptions());
  const auto [front, back] = broker.Start();
  const wire::HealthResponse lonely = ClientFor(broker.admin_endpoint()).Health();
  EXPECT_EQ(lonely.status(), wire::UNAVAILABLE);
  EXPECT_THAT(lonely.reason(), HasSubstr("no worker"));

  HeldMap map(dir / "map", temp / "map");
  ServiceOptions options = LoopbackServiceOptions({back});
  options.admin_bind = testing::IpcEndpoint("worker-admin");
  LocalizationService worker(map.dir(), options);
  auto started = std::async(std::launch::async, [&] { return worker.Start(); });
  EXPECT_EQ(ClientFor(options.admin_bind).Health().status(), wire::LOADING);
  EXPECT_EQ(ClientFor(broker.admin_endpoint()).Health().status(), wire::UNAVAILABLE);

  map.Release();
  started.get();
  EXPECT_EQ(HealthOnceItIs(options.admin_bind, wire::OK).status(), wire::OK);
  const wire::HealthResponse ready = HealthOnceItIs(broker.admin_endpoint(), wire::OK);
  EXPECT_EQ(ready.status(), wire::OK);
  EXPECT_EQ(ready.workers(), 1u);
  worker.Stop();
  broker.Stop();
}

}  // namespace
}  // namespace hscloc
