// Broker mode end to end: a broker, two `hscloc serve --connect` worker processes, clients with
// requests in flight, and one worker killed under load; no request may be lost.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "client/localization_client.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/broker.h"
#include "server/loopback_testing.h"
#include "server/wire.h"
#include "tests/hscloc_process.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

// A worker process: `hscloc serve --connect BACKEND`, its admin endpoint on a free port.
testing::HsclocProcess StartWorker(const fs::path& map, const std::string& backend,
                                   const fs::path& log) {
  return testing::HsclocProcess({"serve", "--map", map.string(), "--connect", backend, "--workers",
                                 "1", "--admin-bind", "tcp://127.0.0.1:0"},
                                log);
}

TEST(ScaleOutTest, AKilledWorkerLosesNoRequest) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  testing::TempDir temp;
  BrokerOptions options = testing::LoopbackBrokerOptions();
  options.heartbeat_interval = std::chrono::milliseconds(200);
  Broker broker(options);
  const auto [front, back] = broker.Start();
  testing::HsclocProcess first = StartWorker(dir / "map", back, temp / "worker1.log");
  testing::HsclocProcess second = StartWorker(dir / "map", back, temp / "worker2.log");

  const std::vector<wire::LocalizeRequest> requests = testing::DayQueryRequests(dir / "city", 30);

  // Both workers load the map and announce themselves before any request: a worker killed before
  // it joined would be one the broker never knew (on a loaded machine the second load may take
  // far longer than the first requests). The deadline bounds a hang, not the load time.
  const auto joined_by = std::chrono::steady_clock::now() + std::chrono::seconds(180);
  while (broker.workers_joined() < 2 && std::chrono::steady_clock::now() < joined_by) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_EQ(broker.workers_joined(), 2u) << "the workers did not join within 180 s";
  ClientOptions client_options;
  client_options.servers = {front};
  client_options.timeout_ms = 120000;
  client_options.retries = 0;
  std::atomic<size_t> next{0};
  std::atomic<size_t> localized{0};
  std::atomic<size_t> answered{0};
  std::vector<std::thread> clients;
  for (int c = 0; c < 4; ++c) {
    clients.emplace_back([&] {
      LocalizationClient client(client_options);
      for (size_t i = next++; i < requests.size(); i = next++) {
        const wire::LocalizeResponse response = client.Localize(requests[i]);
        ++answered;
        localized +=
            response.status() == wire::OK && response.request_id() == requests[i].request_id();
      }
    });
  }
  // Kill one worker once work is under way.
  while (answered < 6) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  first.Kill();
  for (std::thread& client : clients) client.join();
  EXPECT_EQ(answered.load(), requests.size());
  EXPECT_EQ(localized.load(), requests.size());
  // The broker drops the killed worker after heartbeat_liveness silent intervals (0.8 s); the
  // other worker may have answered everything before that. On a machine loaded by other tests the
  // broker's loop may notice it seconds later: the deadline bounds a hang, not the latency.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (broker.workers_dropped() == 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_EQ(broker.workers_dropped(), 1u);
  std::cout << fmt::format("{} requests answered; the broker retried {} after the kill\n",
                           answered.load(), broker.requests_retried());
  EXPECT_EQ(second.Terminate(), 0);
  broker.Stop();
}

}  // namespace
}  // namespace hscloc
