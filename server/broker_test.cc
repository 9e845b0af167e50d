// The broker with CURVE over real loopback sockets: its front admits only clients with the
// server's key and on the allow-list, its back only workers whose keys are listed.
#include "server/broker.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "server/loopback_testing.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

using testing::LoopbackBrokerOptions;
using testing::LoopbackServiceOptions;
using testing::PatientClientOptions;

// Info through the broker (a worker answers it); any map id counts.
wire::Status InfoStatus(const ClientOptions& options) {
  return LocalizationClient(options).Info().map_id().empty() ? wire::INTERNAL : wire::OK;
}

TEST(BrokerTest, CurveFrontRefusesClientsWithoutTheKeyOrNotOnTheAllowList) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  const CurveKeyPair front_keys = GenerateCurveKeyPair();
  const CurveKeyPair allowed = GenerateCurveKeyPair();
  BrokerOptions options = LoopbackBrokerOptions();
  options.curve_secret_key = front_keys.secret_key;
  options.curve_allowed_client_keys = {allowed.public_key};
  Broker broker(options);
  const auto [front, back] = broker.Start();
  LocalizationService worker(dir / "map", LoopbackServiceOptions({back}));
  worker.Start();

  ClientOptions good = PatientClientOptions(front);
  good.curve_server_key = front_keys.public_key;
  good.curve_secret_key = allowed.secret_key;
  EXPECT_EQ(InfoStatus(good), wire::OK);

  ClientOptions stranger = PatientClientOptions(front, 500);
  stranger.curve_server_key = front_keys.public_key;  // a fresh key pair, not on the list
  EXPECT_THROW(InfoStatus(stranger), ClientError);
  EXPECT_THROW(InfoStatus(PatientClientOptions(front, 500)), ClientError);  // no CURVE at all
  EXPECT_EQ(worker.requests_answered(), 1u);
}

TEST(BrokerTest, OnlyWorkersWithAnAllowedKeyReceiveRequests) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  const CurveKeyPair back_keys = GenerateCurveKeyPair();
  const CurveKeyPair listed = GenerateCurveKeyPair();
  const CurveKeyPair unlisted = GenerateCurveKeyPair();
  BrokerOptions options = LoopbackBrokerOptions();
  options.backend_curve_secret_key = back_keys.secret_key;
  options.curve_allowed_worker_keys = {listed.public_key};
  Broker broker(options);
  const auto [front, back] = broker.Start();

  ServiceOptions stranger_options = LoopbackServiceOptions({back});
  stranger_options.curve_secret_key = unlisted.secret_key;
  stranger_options.curve_server_key = back_keys.public_key;
  LocalizationService stranger(dir / "map", stranger_options);
  stranger.Start();
  ServiceOptions plain_options = LoopbackServiceOptions({back});  // no CURVE at all
  LocalizationService plain(dir / "map", plain_options);
  plain.Start();
  ServiceOptions trusted_options = LoopbackServiceOptions({back});
  trusted_options.curve_secret_key = listed.secret_key;
  trusted_options.curve_server_key = back_keys.public_key;
  LocalizationService trusted(dir / "map", trusted_options);
  trusted.Start();

  constexpr int kRequests = 20;
  LocalizationClient client(PatientClientOptions(front));
  for (int i = 0; i < kRequests; ++i) EXPECT_EQ(client.Info().map_id(), MapIdOf(dir / "map")) << i;
  EXPECT_EQ(trusted.requests_answered(), static_cast<size_t>(kRequests));
  EXPECT_EQ(stranger.requests_answered(), 0u);
  EXPECT_EQ(plain.requests_answered(), 0u);
  const wire::HealthResponse refused =
      LocalizationClient(PatientClientOptions(stranger.admin_endpoint())).Health();
  EXPECT_EQ(refused.status(), wire::UNAVAILABLE);
  EXPECT_THAT(refused.reason(), HasSubstr("is this worker's key on its allow-list?"));
  trusted.Stop();
  stranger.Stop();
  plain.Stop();
  broker.Stop();
}

TEST(BrokerTest, SecurityOptionsThatCannotBeHonouredAreRefused) {
  const CurveKeyPair keys = GenerateCurveKeyPair();
  BrokerOptions workers_unlisted = LoopbackBrokerOptions();
  workers_unlisted.backend_curve_secret_key = keys.secret_key;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { workers_unlisted.Check(); }),
              HasSubstr("curve_allowed_worker_keys"));
  BrokerOptions clients_without_key = LoopbackBrokerOptions();
  clients_without_key.curve_allowed_client_keys = {keys.public_key};
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { clients_without_key.Check(); }),
              HasSubstr("--curve-secret-key"));
  ServiceOptions worker = LoopbackServiceOptions({"tcp://127.0.0.1:5556"});
  worker.curve_secret_key = keys.secret_key;  // no broker key to authenticate to
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { worker.Check(); }),
              HasSubstr("--curve-server-key"));
  worker.curve_server_key = keys.public_key;
  worker.curve_allowed_client_keys = {keys.public_key};
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { worker.Check(); }),
              HasSubstr("a worker (--connect) admits no clients"));
}

TEST(BrokerTest, MetricsCountWorkersJoinedAndDroppedAndTheRequestsAnswered) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  BrokerOptions options = LoopbackBrokerOptions();
  options.metrics_bind = "127.0.0.1:0";
  Broker broker(options);
  const auto [front, back] = broker.Start();
  ServiceOptions worker_options = LoopbackServiceOptions({back});
  worker_options.metrics_bind = "127.0.0.1:0";
  LocalizationService worker(dir / "map", worker_options);
  worker.Start();
  LocalizationClient client(PatientClientOptions(front));
  for (int i = 0; i < 5; ++i) EXPECT_EQ(client.Info().map_id(), MapIdOf(dir / "map")) << i;

  std::string text = testing::HttpGet(broker.metrics_url());
  EXPECT_EQ(testing::MetricSample(text, "hscloc_broker_workers_joined_total"), 1);
  EXPECT_EQ(testing::MetricSample(text, R"(hscloc_broker_requests_total{outcome="answered"})"), 5);
  EXPECT_EQ(testing::MetricSample(text, "hscloc_broker_workers"), 1);
  EXPECT_EQ(testing::MetricSample(text, "hscloc_broker_worker_slots"), 1);
  EXPECT_EQ(testing::MetricSample(testing::HttpGet(worker.metrics_url()),
                                  R"(hscloc_requests_total{kind="info",status="OK"})"),
            5);

  // A worker that stops heartbeating is dropped after heartbeat_liveness intervals (400 ms).
  worker.Stop();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (std::chrono::steady_clock::now() < deadline) {
    text = testing::HttpGet(broker.metrics_url());
    if (testing::MetricSample(text, "hscloc_broker_workers_dropped_total") == 1) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_EQ(testing::MetricSample(text, "hscloc_broker_workers_dropped_total"), 1);
  EXPECT_EQ(testing::MetricSample(text, "hscloc_broker_workers"), 0);
  EXPECT_EQ(testing::MetricSample(text, "hscloc_broker_requests_retried_total"), 0);
}

}  // namespace
}  // namespace hscloc
