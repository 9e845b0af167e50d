// deploy/monitoring/: the Grafana dashboard and the Prometheus alerting rules read only metrics
// that the processes export, as a scrape of a real broker and worker shows; promtool accepts the
// rules and their unit tests (deploy/monitoring/alerts_test.yaml) pass.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>

#include "client/localization_client.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/broker.h"
#include "server/localization_service.h"
#include "server/loopback_testing.h"
#include "server/wire.h"
#include "util/testing.h"

namespace hscloc {
namespace {

namespace fs = std::filesystem;

std::string ReadText(const fs::path& path) {
  std::ifstream file(path);
  return std::string(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
}

const fs::path kMonitoring = fs::path(HSCLOC_SOURCE_DIR) / "deploy" / "monitoring";

// The hscloc_ metric families an expression reads; a histogram's _bucket, _sum and _count are its
// family.
std::set<std::string> MetricsIn(const std::string& text) {
  static const std::regex name(R"(hscloc_[a-z_]+)");
  std::set<std::string> metrics;
  for (auto match = std::sregex_iterator(text.begin(), text.end(), name);
       match != std::sregex_iterator(); ++match) {
    std::string metric = match->str();
    for (const std::string suffix : {"_bucket", "_sum", "_count"}) {
      if (metric.size() > suffix.size() &&
          metric.compare(metric.size() - suffix.size(), suffix.size(), suffix) == 0) {
        metric.resize(metric.size() - suffix.size());
      }
    }
    metrics.insert(metric);
  }
  return metrics;
}

// The families a scrape holds, by their "# TYPE" lines.
std::set<std::string> FamiliesIn(const std::string& exposition) {
  static const std::regex type(R"(# TYPE (hscloc_[a-z_]+) )");
  std::set<std::string> families;
  for (auto match = std::sregex_iterator(exposition.begin(), exposition.end(), type);
       match != std::sregex_iterator(); ++match) {
    families.insert((*match)[1].str());
  }
  return families;
}

TEST(MonitoringTest, TheDashboardAndAlertsReadOnlyMetricsTheProcessesExport) {
  HSCLOC_REQUIRE_TRAINED_SMALL_CITY(dir);
  BrokerOptions broker_options = testing::LoopbackBrokerOptions();
  broker_options.metrics_bind = "127.0.0.1:0";
  Broker broker(broker_options);
  const auto [front, back] = broker.Start();
  ServiceOptions worker_options = testing::LoopbackServiceOptions({back});
  worker_options.metrics_bind = "127.0.0.1:0";
  LocalizationService worker(dir / "map", worker_options);
  worker.Start();
  // One query through the broker, so that every family has a sample.
  const wire::LocalizeResponse reply = LocalizationClient(testing::PatientClientOptions(front))
                                           .Localize(testing::DayQueryRequests(dir / "city", 1)[0]);
  ASSERT_EQ(reply.status(), wire::OK) << reply.error_message();
  EXPECT_EQ(reply.map_id(), MapIdOf(dir / "map"));

  std::set<std::string> exported = FamiliesIn(testing::HttpGet(worker.metrics_url()));
  const std::set<std::string> from_broker = FamiliesIn(testing::HttpGet(broker.metrics_url()));
  exported.insert(from_broker.begin(), from_broker.end());
  EXPECT_TRUE(exported.count("hscloc_localize_inliers") && exported.count("hscloc_map_info") &&
              exported.count("hscloc_broker_worker_maps"))
      << fmt::format("{}", fmt::join(exported, " "));

  const nlohmann::json dashboard = nlohmann::json::parse(ReadText(kMonitoring / "dashboard.json"));
  std::set<std::string> used;
  size_t queries = 0;
  for (const nlohmann::json& panel : dashboard.at("panels")) {
    for (const nlohmann::json& target : panel.at("targets")) {
      const std::set<std::string> metrics = MetricsIn(target.at("expr").get<std::string>());
      EXPECT_FALSE(metrics.empty()) << panel.at("title") << ": " << target.at("expr");
      used.insert(metrics.begin(), metrics.end());
      ++queries;
    }
  }
  EXPECT_GE(queries, 8u);
  const std::set<std::string> alerted = MetricsIn(ReadText(kMonitoring / "alerts.yaml"));
  used.insert(alerted.begin(), alerted.end());
  for (const std::string& metric : used) {
    EXPECT_TRUE(exported.count(metric)) << metric << " is read by the dashboard or an alert, and "
                                        << "no process exports it";
  }
  // What the issue asks the dashboard to show: requests, time per stage, inliers, queues, maps.
  for (const std::string metric :
       {"hscloc_requests_total", "hscloc_localize_duration_seconds", "hscloc_localize_inliers",
        "hscloc_broker_queue_depth", "hscloc_map_info", "hscloc_broker_workers"}) {
    EXPECT_TRUE(used.count(metric)) << metric << " is on no panel";
  }
  worker.Stop();
  broker.Stop();
}

TEST(MonitoringTest, PromtoolAcceptsTheAlertRulesAndTheirUnitTestsPass) {
  HSCLOC_REQUIRE_PROMTOOL(promtool);
  testing::TempDir temp;
  EXPECT_EQ(testing::RunCommand(
                fmt::format("{} check rules {}", promtool, (kMonitoring / "alerts.yaml").string()),
                (temp / "check.log").string()),
            0)
      << ReadText(temp / "check.log");
  // promtool resolves rule_files against the working directory.
  EXPECT_EQ(testing::RunCommand(fmt::format("cd {} && {} test rules alerts_test.yaml",
                                            kMonitoring.string(), promtool),
                                (temp / "test.log").string()),
            0)
      << ReadText(temp / "test.log");
}

}  // namespace
}  // namespace hscloc
