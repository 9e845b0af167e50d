// The metrics sets over a real HTTP exposer on loopback, read back as a scrape reads them and
// checked with the real promtool.
#include "server/metrics.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "server/loopback_testing.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using testing::HttpGet;
using ::testing::MatchesRegex;
using testing::MetricSample;

// promtool's verdict on an exposition: empty when it passes, else what it printed.
std::string PromtoolProblems(const std::string& promtool, const std::string& exposition) {
  testing::TempDir dir;
  std::ofstream(dir / "metrics.txt") << exposition;
  const int status = testing::RunCommand(
      promtool + " check metrics < " + (dir / "metrics.txt").string(), (dir / "log").string());
  if (status == 0) return "";
  std::ifstream log(dir / "log");
  std::stringstream text;
  text << log.rdbuf();
  return "exit status " + std::to_string(status) + ": " + text.str();
}

wire::Request RequestOfKind(wire::Request::KindCase kind) {
  wire::Request request;
  if (kind == wire::Request::kLocalize) request.mutable_localize();
  if (kind == wire::Request::kHealth) request.mutable_health();
  return request;
}

TEST(ServiceMetricsTest, AScrapeReadsTheCountsHistogramsAndGauges) {
  ServiceMetrics metrics("127.0.0.1:0");
  ASSERT_THAT(metrics.url(), MatchesRegex("http://127\\.0\\.0\\.1:[0-9]+/metrics"));
  const wire::Request localize = RequestOfKind(wire::Request::kLocalize);
  for (int i = 0; i < 3; ++i) metrics.CountReply(localize, wire::OK);
  metrics.CountReply(localize, wire::OVERLOADED);
  metrics.CountReply(RequestOfKind(wire::Request::kHealth), wire::OK);
  metrics.CountReply(wire::Request(), wire::INVALID_REQUEST);
  StageTimings timings;
  timings.retrieval_ms = 4;
  timings.match_ms = 30;
  timings.visibility_ms = 1;
  timings.pose_ms = 20;
  timings.total_ms = 55;
  metrics.ObserveLocalize(timings, 40, 0.002, 0.060);
  timings.match_ms = 300;
  metrics.ObserveLocalize(timings, 8, 0.002, 0.400);
  metrics.SetQueue(5, 2);
  metrics.SetWorkers(4);
  metrics.CountMapLoad(true);
  metrics.CountMapLoad(false);
  metrics.SetMap("city-a", 1.5);
  metrics.SetMap("city-b", 0.25);

  const std::string text = HttpGet(metrics.url());
  EXPECT_EQ(text, metrics.Text());
  EXPECT_EQ(MetricSample(text, R"(hscloc_requests_total{kind="localize",status="OK"})"), 3);
  EXPECT_EQ(MetricSample(text, R"(hscloc_requests_total{kind="localize",status="OVERLOADED"})"), 1);
  EXPECT_EQ(MetricSample(text, R"(hscloc_requests_total{kind="health",status="OK"})"), 1);
  EXPECT_EQ(MetricSample(text, R"(hscloc_requests_total{kind="none",status="INVALID_REQUEST"})"),
            1);
  // Both matches fall in the 0.5 s bucket, one of them in the 0.05 s bucket.
  EXPECT_EQ(MetricSample(text, R"(hscloc_localize_duration_seconds_count{stage="match"})"), 2);
  EXPECT_EQ(
      MetricSample(text, R"(hscloc_localize_duration_seconds_bucket{stage="match",le="0.05"})"), 1);
  EXPECT_EQ(
      MetricSample(text, R"(hscloc_localize_duration_seconds_bucket{stage="match",le="0.5"})"), 2);
  EXPECT_DOUBLE_EQ(*MetricSample(text, R"(hscloc_localize_duration_seconds_sum{stage="server"})"),
                   0.46);
  // 8 inliers fall under the 12 a pose needs, 40 above.
  EXPECT_EQ(MetricSample(text, R"(hscloc_localize_inliers_bucket{le="10"})"), 1);
  EXPECT_EQ(MetricSample(text, R"(hscloc_localize_inliers_bucket{le="50"})"), 2);
  EXPECT_EQ(MetricSample(text, "hscloc_localize_inliers_sum"), 48);
  EXPECT_EQ(MetricSample(text, "hscloc_queue_depth"), 5);
  EXPECT_EQ(MetricSample(text, "hscloc_requests_in_flight"), 2);
  EXPECT_EQ(MetricSample(text, "hscloc_workers"), 4);
  EXPECT_EQ(MetricSample(text, R"(hscloc_map_loads_total{outcome="success"})"), 1);
  EXPECT_EQ(MetricSample(text, R"(hscloc_map_loads_total{outcome="failure"})"), 1);
  // Only the map served now is labelled.
  EXPECT_EQ(MetricSample(text, R"(hscloc_map_info{map_id="city-b"})"), 1);
  EXPECT_EQ(MetricSample(text, R"(hscloc_map_info{map_id="city-a"})"), std::nullopt);
  EXPECT_EQ(MetricSample(text, "hscloc_map_load_seconds"), 0.25);
  EXPECT_GT(*MetricSample(text, "hscloc_map_loaded_timestamp_seconds"), 1.7e9);
}

TEST(ServiceMetricsTest, PromtoolAcceptsTheExposition) {
  HSCLOC_REQUIRE_PROMTOOL(promtool);
  ServiceMetrics service("127.0.0.1:0");
  service.CountReply(RequestOfKind(wire::Request::kLocalize), wire::OK);
  service.ObserveLocalize(StageTimings(), 0, 0, 0.01);
  service.SetMap("small", 0.4);
  EXPECT_EQ(PromtoolProblems(promtool, HttpGet(service.url())), "");
  BrokerMetrics broker("127.0.0.1:0");
  broker.CountAnswered();
  broker.CountWorkerJoined();
  broker.SetWorkerMaps({{"small@0123", 1}});
  EXPECT_EQ(PromtoolProblems(promtool, HttpGet(broker.url())), "");
}

TEST(ServiceMetricsTest, PromtoolCatchesABrokenExposition) {
  HSCLOC_REQUIRE_PROMTOOL(promtool);
  // The check above could not fail if promtool accepted anything.
  EXPECT_NE(PromtoolProblems(promtool, "# TYPE hscloc_things counter\nhscloc_things 1\n"), "");
}

TEST(BrokerMetricsTest, AScrapeReadsTheWorkersAndRetries) {
  BrokerMetrics metrics("127.0.0.1:0");
  metrics.CountWorkerJoined();
  metrics.CountWorkerJoined();
  metrics.CountWorkerDropped(3);
  for (int i = 0; i < 7; ++i) metrics.CountAnswered();
  metrics.CountOverloaded();
  metrics.SetQueue(12, 4);
  metrics.SetWorkers(1, 4);
  metrics.SetWorkerMaps({{"city@aaaa", 2}, {"city@bbbb", 1}});
  metrics.SetWorkerMaps({{"city@bbbb", 3}});  // the update rolled over every worker
  const std::string text = HttpGet(metrics.url());
  EXPECT_EQ(MetricSample(text, R"(hscloc_broker_worker_maps{map_id="city@bbbb"})"), 3);
  EXPECT_EQ(MetricSample(text, R"(hscloc_broker_worker_maps{map_id="city@aaaa"})"), std::nullopt);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_workers_joined_total"), 2);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_workers_dropped_total"), 1);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_requests_retried_total"), 3);
  EXPECT_EQ(MetricSample(text, R"(hscloc_broker_requests_total{outcome="answered"})"), 7);
  EXPECT_EQ(MetricSample(text, R"(hscloc_broker_requests_total{outcome="overloaded"})"), 1);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_queue_depth"), 12);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_requests_in_flight"), 4);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_workers"), 1);
  EXPECT_EQ(MetricSample(text, "hscloc_broker_worker_slots"), 4);
}

TEST(ServiceMetricsTest, WithoutABindAddressTheyAreCountedNotExposed) {
  ServiceMetrics metrics("");
  EXPECT_EQ(metrics.url(), "");
  metrics.CountReply(RequestOfKind(wire::Request::kHealth), wire::OK);
  EXPECT_EQ(MetricSample(metrics.Text(), R"(hscloc_requests_total{kind="health",status="OK"})"), 1);
}

TEST(ServiceMetricsTest, TheEndpointAnswersOtherPathsMethodsAndGarbageWithHttpErrors) {
  ServiceMetrics metrics("127.0.0.1:0");
  const std::string root = metrics.url().substr(0, metrics.url().rfind('/'));
  EXPECT_THAT(testing::HttpExchange(root + "/other", "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n"),
              ::testing::StartsWith("HTTP/1.1 404"));
  EXPECT_THAT(testing::HttpExchange(metrics.url(), "POST {path} HTTP/1.1\r\n\r\n"),
              ::testing::StartsWith("HTTP/1.1 405"));
  EXPECT_THAT(testing::HttpExchange(metrics.url(), "hello\r\n\r\n"),
              ::testing::StartsWith("HTTP/1.1 400"));
  const std::string head = testing::HttpExchange(metrics.url(), "HEAD {path} HTTP/1.1\r\n\r\n");
  EXPECT_THAT(head, ::testing::StartsWith("HTTP/1.1 200"));
  EXPECT_THAT(head, HasSubstr("Content-Type: text/plain; version=0.0.4"));
  EXPECT_THAT(head, ::testing::EndsWith("\r\n\r\n"));  // no body
  // A query string is ignored, as Prometheus's own exporters do.
  EXPECT_THAT(testing::HttpExchange(metrics.url() + "?x=1", "GET {path} HTTP/1.0\r\n\r\n"),
              HasSubstr("hscloc_queue_depth 0"));
  // A scraper that connects and says nothing holds the endpoint for 2 s at most.
  EXPECT_THAT(testing::HttpExchange(metrics.url(), ""), ::testing::StartsWith("HTTP/1.1 400"));
  EXPECT_THAT(HttpGet(metrics.url()), HasSubstr("hscloc_workers"));
}

TEST(ServiceMetricsTest, ABadBindAddressIsAClearError) {
  for (const std::string bind : {"9464", "localhost", "127.0.0.1:port", "127.0.0.1:999999"}) {
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { ServiceMetrics metrics(bind); }),
                HasSubstr("--metrics-bind '" + bind + "': expected host:port"))
        << bind;
  }
  ServiceMetrics taken("127.0.0.1:0");
  const std::string port = taken.url().substr(taken.url().rfind(':') + 1);
  const std::string bind = "127.0.0.1:" + port.substr(0, port.find('/'));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { BrokerMetrics metrics(bind); }),
              HasSubstr("cannot serve metrics on " + bind + " (--metrics-bind)"));
}

}  // namespace
}  // namespace hscloc
