// Prometheus metrics of a serving process (DESIGN.md, "Serving and scale"): what an operator
// watches and what an autoscaler scales on. A service and a broker each own one set (a
// prometheus-cpp registry), exposed in the text format at http://<bind>/metrics
// (server/metrics_http_server.h) when a bind address is given; every update is a few atomic
// operations on the request path.
//
// The names, all prefixed hscloc_:
//   service  requests_total{kind, status}            replies sent, by request kind and status
//            localize_duration_seconds{stage}         queue, retrieval, match, visibility, pose,
//                                                     localize (the Localizer) and server (receipt
//                                                     to reply), as histograms
//            localize_inliers                         the returned pose's inliers, a histogram
//            queue_depth, requests_in_flight, workers
//            map_info{map_id}                         1 for the map served
//            map_load_seconds, map_loaded_timestamp_seconds
//            map_loads_total{outcome}                 every load of the map directory, the first
//                                                     included: success or failure
//   broker   broker_requests_total{outcome}          answered, overloaded
//            broker_queue_depth, broker_requests_in_flight, broker_workers, broker_worker_slots
//            broker_worker_maps{map_id}              workers by the map they serve
//            broker_workers_joined_total, broker_workers_dropped_total,
//            broker_requests_retried_total
#pragma once

#include <map>
#include <memory>
#include <string>
#include <string_view>

#include "localization/stage_timings.h"
#include "server/wire.h"

namespace hscloc {

namespace metrics_internal {
struct Endpoint;
}  // namespace metrics_internal

// `bind` is "host:port" (port 0: a free one), e.g. "0.0.0.0:9464" in a container or
// "127.0.0.1:0" in a test; empty: counted, not exposed. Throws std::invalid_argument when the
// address cannot be bound, naming `option`.
class ServiceMetrics {
 public:
  explicit ServiceMetrics(const std::string& bind, const std::string& option = "--metrics-bind");
  ~ServiceMetrics();
  ServiceMetrics(const ServiceMetrics&) = delete;
  ServiceMetrics& operator=(const ServiceMetrics&) = delete;

  // "http://host:port/metrics" as bound, or empty when not exposed.
  const std::string& url() const;
  // The exposition text, as a scrape reads it.
  std::string Text() const;

  // A reply to a request (`request` may be empty: the message could not be decoded).
  void CountReply(const wire::Request& request, wire::Status status);
  // A Localize request's stages, the inliers of its pose, its wait in the queue and its time
  // from receipt to reply.
  void ObserveLocalize(const StageTimings& timings, size_t inliers, double queue_seconds,
                       double server_seconds);
  void SetQueue(size_t waiting, size_t running);
  void SetWorkers(int workers);
  void CountMapLoad(bool success);
  // The map now served, and how long its load and verification took.
  void SetMap(const std::string& map_id, double load_seconds);

 private:
  struct Families;
  std::unique_ptr<metrics_internal::Endpoint> endpoint_;
  std::unique_ptr<Families> families_;
};

class BrokerMetrics {
 public:
  explicit BrokerMetrics(const std::string& bind, const std::string& option = "--metrics-bind");
  ~BrokerMetrics();
  BrokerMetrics(const BrokerMetrics&) = delete;
  BrokerMetrics& operator=(const BrokerMetrics&) = delete;

  const std::string& url() const;
  std::string Text() const;

  void CountAnswered();
  void CountOverloaded();
  void CountWorkerJoined();
  void CountWorkerDropped(size_t requests_retried);
  void SetQueue(size_t waiting, size_t in_flight);
  void SetWorkers(size_t workers, size_t slots);
  void SetWorkerMaps(const std::map<std::string, size_t>& workers_by_map);

 private:
  struct Families;
  std::unique_ptr<metrics_internal::Endpoint> endpoint_;
  std::unique_ptr<Families> families_;
};

// The kind of a request as the metrics label it: localize, health, info, reload, none.
std::string_view RequestKindName(const wire::Request& request);

}  // namespace hscloc
