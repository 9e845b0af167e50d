#include "server/metrics.h"

#include <prometheus/counter.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

#include <chrono>
#include <mutex>

#include "server/metrics_http_server.h"
#include "util/check.h"

namespace hscloc {

namespace metrics_internal {

// One registry, exposed over HTTP when a bind address is given.
struct Endpoint {
  std::shared_ptr<prometheus::Registry> registry = std::make_shared<prometheus::Registry>();
  std::unique_ptr<MetricsHttpServer> server;

  Endpoint(const std::string& bind, const std::string& option) {
    if (bind.empty()) return;
    server = std::make_unique<MetricsHttpServer>(bind, option, [this] { return Text(); });
  }

  std::string Text() const { return prometheus::TextSerializer().Serialize(registry->Collect()); }
  const std::string& url() const {
    static const std::string kNone;
    return server == nullptr ? kNone : server->url();
  }
};

}  // namespace metrics_internal

namespace {

using prometheus::BuildCounter;
using prometheus::BuildGauge;
using prometheus::BuildHistogram;

// From 1 ms to 20 s: a query's stages take milliseconds, a request waiting behind a full queue
// seconds.
prometheus::Histogram::BucketBoundaries DurationBuckets() {
  return {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 20};
}

double UnixSeconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

// A metric without labels, the only one of its family.
prometheus::Gauge& SingleGauge(prometheus::Registry& registry, const std::string& name,
                               const std::string& help) {
  return BuildGauge().Name(name).Help(help).Register(registry).Add({});
}

prometheus::Counter& SingleCounter(prometheus::Registry& registry, const std::string& name,
                                   const std::string& help) {
  return BuildCounter().Name(name).Help(help).Register(registry).Add({});
}

}  // namespace

std::string_view RequestKindName(const wire::Request& request) {
  switch (request.kind_case()) {
    case wire::Request::kLocalize:
      return "localize";
    case wire::Request::kHealth:
      return "health";
    case wire::Request::kInfo:
      return "info";
    case wire::Request::kReload:
      return "reload";
    default:
      return "none";
  }
}

struct ServiceMetrics::Families {
  prometheus::Family<prometheus::Counter>& requests;
  prometheus::Family<prometheus::Histogram>& durations;
  prometheus::Histogram* stage[7];  // queue, retrieval, match, visibility, pose, localize, server
  prometheus::Histogram& inliers;
  prometheus::Gauge& queue_depth;
  prometheus::Gauge& in_flight;
  prometheus::Gauge& workers;
  prometheus::Family<prometheus::Gauge>& map_info;
  prometheus::Gauge& map_load_seconds;
  prometheus::Gauge& map_loaded_timestamp;
  prometheus::Family<prometheus::Counter>& map_loads;
  std::mutex map_mutex;
  prometheus::Gauge* current_map = nullptr;

  explicit Families(prometheus::Registry& registry)
      : requests(BuildCounter()
                     .Name("hscloc_requests_total")
                     .Help("Replies sent, by request kind and reply status")
                     .Register(registry)),
        durations(BuildHistogram()
                      .Name("hscloc_localize_duration_seconds")
                      .Help("Localize requests: time per stage (queue: waiting for a worker; "
                            "localize: the Localizer's total; server: receipt to reply)")
                      .Register(registry)),
        inliers(BuildHistogram()
                    .Name("hscloc_localize_inliers")
                    .Help("Localize requests answered with a pose or NOT_LOCALIZED: the inliers "
                          "of the pose returned (0 when there is none)")
                    .Register(registry)
                    .Add({}, prometheus::Histogram::BucketBoundaries{0, 5, 10, 12, 20, 30, 50, 100,
                                                                     200, 500})),
        queue_depth(
            SingleGauge(registry, "hscloc_queue_depth", "Localize requests waiting for a worker")),
        in_flight(SingleGauge(registry, "hscloc_requests_in_flight",
                              "Localize requests being localized")),
        workers(SingleGauge(registry, "hscloc_workers", "Worker threads of this process")),
        map_info(BuildGauge()
                     .Name("hscloc_map_info")
                     .Help("1 for the map this process serves, labelled by its id")
                     .Register(registry)),
        map_load_seconds(SingleGauge(registry, "hscloc_map_load_seconds",
                                     "Time to load and verify the map served")),
        map_loaded_timestamp(SingleGauge(registry, "hscloc_map_loaded_timestamp_seconds",
                                         "When the map served was loaded (Unix time)")),
        map_loads(BuildCounter()
                      .Name("hscloc_map_loads_total")
                      .Help("Loads of the map directory (start and reloads), by outcome; a "
                            "failed load leaves the previous map serving")
                      .Register(registry)) {
    const char* stages[] = {"queue", "retrieval", "match", "visibility",
                            "pose",  "localize",  "server"};
    for (int i = 0; i < 7; ++i)
      stage[i] = &durations.Add({{"stage", stages[i]}}, DurationBuckets());
    map_loads.Add({{"outcome", "success"}});
    map_loads.Add({{"outcome", "failure"}});
  }
};

ServiceMetrics::ServiceMetrics(const std::string& bind, const std::string& option)
    : endpoint_(std::make_unique<metrics_internal::Endpoint>(bind, option)),
      families_(std::make_unique<Families>(*endpoint_->registry)) {}

ServiceMetrics::~ServiceMetrics() = default;

const std::string& ServiceMetrics::url() const { return endpoint_->url(); }

std::string ServiceMetrics::Text() const { return endpoint_->Text(); }

void ServiceMetrics::CountReply(const wire::Request& request, wire::Status status) {
  families_->requests
      .Add({{"kind", std::string(RequestKindName(request))}, {"status", StatusName(status)}})
      .Increment();
}

void ServiceMetrics::ObserveLocalize(const StageTimings& timings, size_t inliers,
                                     double queue_seconds, double server_seconds) {
  families_->inliers.Observe(static_cast<double>(inliers));
  const double seconds[7] = {queue_seconds,           timings.retrieval_ms * 1e-3,
                             timings.match_ms * 1e-3, timings.visibility_ms * 1e-3,
                             timings.pose_ms * 1e-3,  timings.total_ms * 1e-3,
                             server_seconds};
  for (int i = 0; i < 7; ++i) families_->stage[i]->Observe(seconds[i]);
}

void ServiceMetrics::SetQueue(size_t waiting, size_t running) {
  families_->queue_depth.Set(static_cast<double>(waiting));
  families_->in_flight.Set(static_cast<double>(running));
}

void ServiceMetrics::SetWorkers(int workers) { families_->workers.Set(workers); }

void ServiceMetrics::CountMapLoad(bool success) {
  families_->map_loads.Add({{"outcome", success ? "success" : "failure"}}).Increment();
}

void ServiceMetrics::SetMap(const std::string& map_id, double load_seconds) {
  std::lock_guard<std::mutex> lock(families_->map_mutex);
  if (families_->current_map != nullptr) families_->map_info.Remove(families_->current_map);
  families_->current_map = &families_->map_info.Add({{"map_id", map_id}});
  families_->current_map->Set(1);
  families_->map_load_seconds.Set(load_seconds);
  families_->map_loaded_timestamp.Set(UnixSeconds());
}

struct BrokerMetrics::Families {
  prometheus::Counter& answered;
  prometheus::Counter& overloaded;
  prometheus::Gauge& queue_depth;
  prometheus::Gauge& in_flight;
  prometheus::Gauge& workers;
  prometheus::Gauge& slots;
  prometheus::Counter& joined;
  prometheus::Counter& dropped;
  prometheus::Counter& retried;
  prometheus::Family<prometheus::Gauge>& worker_maps;
  std::map<std::string, size_t> published_maps;  // what worker_maps shows now

  explicit Families(prometheus::Registry& registry)
      : Families(registry, BuildCounter()
                               .Name("hscloc_broker_requests_total")
                               .Help("Client requests by outcome: answered by a worker, or "
                                     "refused OVERLOADED by the broker")
                               .Register(registry)) {}

  Families(prometheus::Registry& registry, prometheus::Family<prometheus::Counter>& requests)
      : answered(requests.Add({{"outcome", "answered"}})),
        overloaded(requests.Add({{"outcome", "overloaded"}})),
        queue_depth(SingleGauge(registry, "hscloc_broker_queue_depth",
                                "Requests waiting for a free worker slot: what to scale on")),
        in_flight(SingleGauge(registry, "hscloc_broker_requests_in_flight",
                              "Requests handed to a worker and not yet answered")),
        workers(
            SingleGauge(registry, "hscloc_broker_workers", "Workers heartbeating to the broker")),
        slots(SingleGauge(registry, "hscloc_broker_worker_slots",
                          "Requests the workers take at once, in all")),
        joined(SingleCounter(registry, "hscloc_broker_workers_joined_total",
                             "Workers that announced themselves")),
        dropped(SingleCounter(registry, "hscloc_broker_workers_dropped_total",
                              "Workers dropped after missing their heartbeats")),
        retried(SingleCounter(registry, "hscloc_broker_requests_retried_total",
                              "Requests a dropped worker held, handed to another")),
        worker_maps(BuildGauge()
                        .Name("hscloc_broker_worker_maps")
                        .Help("Workers heartbeating to the broker, by the id of the map they "
                              "serve (two ids while a map update rolls)")
                        .Register(registry)) {}
};

BrokerMetrics::BrokerMetrics(const std::string& bind, const std::string& option)
    : endpoint_(std::make_unique<metrics_internal::Endpoint>(bind, option)),
      families_(std::make_unique<Families>(*endpoint_->registry)) {}

BrokerMetrics::~BrokerMetrics() = default;

const std::string& BrokerMetrics::url() const { return endpoint_->url(); }

std::string BrokerMetrics::Text() const { return endpoint_->Text(); }

void BrokerMetrics::CountAnswered() { families_->answered.Increment(); }

void BrokerMetrics::CountOverloaded() { families_->overloaded.Increment(); }

void BrokerMetrics::CountWorkerJoined() { families_->joined.Increment(); }

void BrokerMetrics::CountWorkerDropped(size_t requests_retried) {
  families_->dropped.Increment();
  families_->retried.Increment(static_cast<double>(requests_retried));
}

void BrokerMetrics::SetQueue(size_t waiting, size_t in_flight) {
  families_->queue_depth.Set(static_cast<double>(waiting));
  families_->in_flight.Set(static_cast<double>(in_flight));
}

void BrokerMetrics::SetWorkers(size_t workers, size_t slots) {
  families_->workers.Set(static_cast<double>(workers));
  families_->slots.Set(static_cast<double>(slots));
}

void BrokerMetrics::SetWorkerMaps(const std::map<std::string, size_t>& workers_by_map) {
  if (workers_by_map == families_->published_maps) return;
  for (const auto& [map_id, count] : families_->published_maps) {
    if (workers_by_map.count(map_id) == 0) {
      families_->worker_maps.Remove(&families_->worker_maps.Add({{"map_id", map_id}}));
    }
  }
  for (const auto& [map_id, count] : workers_by_map) {
    families_->worker_maps.Add({{"map_id", map_id}}).Set(static_cast<double>(count));
  }
  families_->published_maps = workers_by_map;
}

}  // namespace hscloc
