// No single point of failure, end to end on loopback: two brokers and two workers as processes,
// each worker registered with both brokers, and `hscloc-client` given both brokers. Every process
// is killed (SIGKILL) in turn under steady load and restarted; every batch must come back whole
// and identical to the fault-free one. Then a map update rolled over the workers under load.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <atomic>
#include <chrono>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <thread>

#include "client/localization_client.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/broker.h"
#include "server/localization_service.h"
#include "server/loopback_testing.h"
#include "server/wire.h"
#include "tests/hscloc_process.h"
#include "util/testing.h"
#include "util/timer.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;
using testing::HsclocProcess;
using testing::ReadText;

// A loopback TCP port free now, below the kernel's range of ephemeral ports, so that a killed
// broker restarts on it: no outgoing connection (a test's, or a worker's reconnecting to this very
// port) is ever given it meanwhile, nor connects to itself on it.
int FreePort() {
  int ephemeral_low = 32768;
  std::ifstream("/proc/sys/net/ipv4/ip_local_port_range") >> ephemeral_low;
  static std::mt19937 random(std::random_device{}());
  std::uniform_int_distribution<int> candidates(10000, std::max(10001, ephemeral_low - 1));
  for (int attempt = 0; attempt < 1000; ++attempt) {
    const int port = candidates(random);
    const int probe = socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = htons(static_cast<uint16_t>(port));
    const bool free = bind(probe, reinterpret_cast<sockaddr*>(&address), sizeof(address)) == 0;
    close(probe);
    if (free) return port;
  }
  throw std::runtime_error("no free loopback port below the ephemeral range");
}

struct BrokerEndpoints {
  std::string front;
  std::string back;
};

BrokerEndpoints LoopbackEndpoints() {
  return {fmt::format("tcp://127.0.0.1:{}", FreePort()),
          fmt::format("tcp://127.0.0.1:{}", FreePort())};
}

std::unique_ptr<HsclocProcess> StartBroker(const BrokerEndpoints& endpoints, const fs::path& log) {
  return std::make_unique<HsclocProcess>(
      std::vector<std::string>{"serve", "--broker", "--bind", endpoints.front, "--backend",
                               endpoints.back, "--admin-bind", "tcp://127.0.0.1:0"},
      log);
}

std::unique_ptr<HsclocProcess> StartWorker(const fs::path& map,
                                           const std::vector<BrokerEndpoints>& brokers,
                                           const fs::path& log) {
  std::vector<std::string> arguments = {"serve", "--map",        map.string(),       "--workers",
                                        "1",     "--admin-bind", "tcp://127.0.0.1:0"};
  for (const BrokerEndpoints& broker : brokers) {
    arguments.push_back("--connect");
    arguments.push_back(broker.back);
  }
  return std::make_unique<HsclocProcess>(arguments, log);
}

// The workers a broker hears from, asked on its admin endpoint; -1 without a reply.
int WorkersOf(const HsclocProcess& broker) {
  const std::string admin = broker.WaitForLine("admin on ");
  if (admin.empty()) return -1;
  ClientOptions options;
  options.servers = {admin};
  options.timeout_ms = 2000;
  options.retries = 0;
  try {
    return LocalizationClient(options).Health().worker_status_size();
  } catch (const ClientError&) {
    return -1;
  }
}

// Waits up to a minute for the broker to hear from `workers` workers.
bool WaitForWorkers(const HsclocProcess& broker, int workers) {
  for (int wait = 0; wait < 600; ++wait) {
    if (WorkersOf(broker) == workers) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return false;
}

// Every process's log under `dir`, for a failure's message: which process missed what.
std::string AllLogs(const fs::path& dir) {
  std::string logs;
  for (const fs::directory_entry& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() != ".log") continue;
    logs += fmt::format("--- {}\n{}\n", entry.path().filename().string(), ReadText(entry.path()));
  }
  return logs;
}

// `hscloc-client batch` over the day queries through every broker given; its exit status.
int RunClientBatch(const fs::path& city, const std::vector<BrokerEndpoints>& brokers,
                   const fs::path& out) {
  std::string servers;
  for (const BrokerEndpoints& broker : brokers) servers += " --server " + broker.front;
  return testing::RunCommand(
      fmt::format("{}{} batch --queries {} --features {} --out {} --inflight 4",
                  HSCLOC_CLIENT_BINARY, servers,
                  (city / "queries" / "day_time_queries_with_intrinsics.txt").string(),
                  (city / "features.h5").string(), out.string()),
      out.string() + ".log");
}

TEST(FailoverTest, KillingAnyOneProcessCostsLatencyNeverAnAnswer) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  testing::TempDir temp;
  const std::vector<BrokerEndpoints> brokers = {LoopbackEndpoints(), LoopbackEndpoints()};
  std::unique_ptr<HsclocProcess> broker_a = StartBroker(brokers[0], temp / "broker-a.log");
  std::unique_ptr<HsclocProcess> broker_b = StartBroker(brokers[1], temp / "broker-b.log");
  std::unique_ptr<HsclocProcess> worker_1 = StartWorker(dir / "map", brokers, temp / "w1.log");
  std::unique_ptr<HsclocProcess> worker_2 = StartWorker(dir / "map", brokers, temp / "w2.log");
  ASSERT_TRUE(WaitForWorkers(*broker_a, 2)) << broker_a->Log() << worker_1->Log();
  ASSERT_TRUE(WaitForWorkers(*broker_b, 2)) << broker_b->Log() << worker_2->Log();

  const fs::path reference = temp / "fault-free.txt";
  ASSERT_EQ(RunClientBatch(dir / "city", brokers, reference), 0)
      << ReadText(reference.string() + ".log");
  const std::string expected = ReadText(reference);
  ASSERT_EQ(std::count(expected.begin(), expected.end(), '\n'), 50);

  // Batches back to back while the processes die, until the last fault has been survived.
  std::atomic<bool> faults_done{false};
  std::vector<std::pair<int, fs::path>> batches;
  std::thread load([&] {
    while (!faults_done || batches.size() < 2) {
      const fs::path out = temp / fmt::format("batch-{}.txt", batches.size());
      batches.emplace_back(RunClientBatch(dir / "city", brokers, out), out);
    }
  });
  const auto pause = [] { std::this_thread::sleep_for(std::chrono::milliseconds(1500)); };
  pause();
  broker_a->Kill();
  pause();
  worker_1->Kill();
  pause();
  broker_a = StartBroker(brokers[0], temp / "broker-a2.log");
  EXPECT_TRUE(WaitForWorkers(*broker_a, 1)) << broker_a->Log();
  broker_b->Kill();
  pause();
  worker_1 = StartWorker(dir / "map", brokers, temp / "w1b.log");
  broker_b = StartBroker(brokers[1], temp / "broker-b2.log");
  EXPECT_TRUE(WaitForWorkers(*broker_a, 2)) << broker_a->Log();
  worker_2->Kill();
  pause();
  faults_done = true;
  load.join();

  ASSERT_GE(batches.size(), 2u);
  bool whole = true;
  for (const auto& [status, out] : batches) {
    EXPECT_EQ(status, 0) << out << ": " << ReadText(out.string() + ".log");
    EXPECT_EQ(ReadText(out), expected) << out << " differs from the fault-free run";
    whole = whole && status == 0 && ReadText(out) == expected;
  }
  if (!whole) std::cout << AllLogs(temp.path());
  std::cout << fmt::format("{} batches of 50 queries through 5 kills, all whole and identical\n",
                           batches.size());
}

// A copy of the map bundle that differs in its manifest only (hard links to the blobs): another
// map id for the same poses.
void CopyWithAnotherManifest(const fs::path& map, const fs::path& copy) {
  fs::create_directories(copy);
  for (const fs::directory_entry& entry : fs::directory_iterator(map)) {
    if (entry.path().filename() == "manifest.json") continue;
    fs::create_hard_link(entry.path(), copy / entry.path().filename());
  }
  nlohmann::json manifest = nlohmann::json::parse(ReadText(map / "manifest.json"));
  manifest["metadata"]["revision"] = "rolled";
  std::ofstream(copy / "manifest.json") << manifest.dump(2);
}

TEST(FailoverTest, AMapUpdateRollsOverTheWorkersUnderLoadWithNoFailedRequest) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  testing::TempDir temp;
  CopyWithAnotherManifest(dir / "map", temp / "next");
  // Each worker serves the directory a link names; the update turns the link and reloads.
  fs::create_directory_symlink(dir / "map", temp / "served");
  Broker broker(testing::LoopbackBrokerOptions());
  const auto [front, back] = broker.Start();
  std::vector<std::unique_ptr<LocalizationService>> workers;
  for (int i = 0; i < 2; ++i) {
    workers.push_back(std::make_unique<LocalizationService>(
        temp / "served", testing::LoopbackServiceOptions({back})));
    workers.back()->Start();
  }
  const std::string old_id = MapIdOf(dir / "map");
  const std::string new_id = MapIdOf(temp / "next");
  ASSERT_NE(old_id, new_id);

  const std::vector<wire::LocalizeRequest> requests = testing::DayQueryRequests(dir / "city", 50);
  std::atomic<bool> rolled{false};
  std::atomic<size_t> failed{0};
  std::atomic<size_t> answered_after_roll{0};
  std::atomic<size_t> old_after_roll{0};
  std::mutex seen_mutex;
  std::set<std::string> seen;
  std::vector<std::thread> clients;
  for (int c = 0; c < 2; ++c) {
    clients.emplace_back([&, c] {
      LocalizationClient client(testing::PatientClientOptions(front));
      for (size_t i = c; !rolled || answered_after_roll < 20; ++i) {
        const bool after_roll = rolled;
        const wire::LocalizeResponse reply = client.Localize(requests[i % requests.size()]);
        failed += reply.status() != wire::OK;
        std::lock_guard<std::mutex> lock(seen_mutex);
        seen.insert(reply.map_id());
        if (after_roll) {
          ++answered_after_roll;
          old_after_roll += reply.map_id() != new_id;
        }
      }
    });
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  fs::create_directory_symlink(temp / "next", temp / "turning");
  fs::rename(temp / "turning", temp / "served");  // atomic: a reload sees one map or the other
  // deploy/roll-map.sh reloads each worker on its admin endpoint, one at a time.
  const fs::path roll_log = temp / "roll.log";
  EXPECT_EQ(
      testing::RunCommand(fmt::format("bash {}/deploy/roll-map.sh --client {} {} {}",
                                      HSCLOC_SOURCE_DIR, HSCLOC_CLIENT_BINARY,
                                      workers[0]->admin_endpoint(), workers[1]->admin_endpoint()),
                          roll_log.string()),
      0)
      << ReadText(roll_log);
  EXPECT_THAT(ReadText(roll_log), ::testing::HasSubstr("2 workers serve " + new_id));
  for (const std::unique_ptr<LocalizationService>& worker : workers) {
    EXPECT_EQ(worker->map_id(), new_id);
  }
  rolled = true;
  for (std::thread& client : clients) client.join();
  EXPECT_EQ(failed.load(), 0u);
  EXPECT_EQ(old_after_roll.load(), 0u) << "a reply after the roll came from the old map";
  EXPECT_EQ(seen, (std::set<std::string>{old_id, new_id}));
  // The broker's Health names the map each worker serves, once both have announced the new one.
  ClientOptions broker_admin = testing::PatientClientOptions(broker.admin_endpoint());
  std::multiset<std::string> worker_maps;
  // The deadline bounds a hang; a loaded machine may take seconds to announce.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (std::chrono::steady_clock::now() < deadline) {
    worker_maps.clear();
    const wire::HealthResponse health = LocalizationClient(broker_admin).Health();
    for (const wire::WorkerStatus& worker : health.worker_status()) {
      worker_maps.insert(worker.map_id());
    }
    if (worker_maps == std::multiset<std::string>{new_id, new_id}) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_EQ(worker_maps, (std::multiset<std::string>{new_id, new_id}));

  // A map that fails verification stops the roll at the first worker, which keeps its map.
  fs::create_directory(temp / "broken");
  std::ofstream(temp / "broken" / "manifest.json") << "{}";
  fs::create_directory_symlink(temp / "broken", temp / "turning");
  fs::rename(temp / "turning", temp / "served");
  EXPECT_NE(
      testing::RunCommand(fmt::format("bash {}/deploy/roll-map.sh --client {} {} {}",
                                      HSCLOC_SOURCE_DIR, HSCLOC_CLIENT_BINARY,
                                      workers[0]->admin_endpoint(), workers[1]->admin_endpoint()),
                          roll_log.string()),
      0);
  EXPECT_THAT(ReadText(roll_log), ::testing::HasSubstr("the roll stops here"));
  EXPECT_EQ(workers[0]->map_id(), new_id);
  EXPECT_EQ(workers[0]->reloads_executed(), 3u);
  EXPECT_EQ(workers[1]->reloads_executed(), 2u);  // never asked
  for (const std::unique_ptr<LocalizationService>& worker : workers) worker->Stop();
  broker.Stop();
}

}  // namespace
}  // namespace hscloc
