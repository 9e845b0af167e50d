// The localization service: a ZeroMQ ROUTER socket in front of a pool of worker threads that share
// one read-only map (DESIGN.md, "Serving and scale").
//
// The front thread owns the sockets. It decodes each request envelope, answers Health and Info at
// once (so probes answer under load), refuses what it cannot decode, and queues Localize requests
// for the workers, answering OVERLOADED when the bounded queue is full. Workers localize against
// the map they find when they start a request and hand their reply back to the front thread,
// which alone writes to the sockets. Every request gets exactly one reply.
//
// Besides the public socket the service binds an admin endpoint (loopback by default): the only
// place, with the keys of an admin CURVE allow-list, where Reload is accepted; elsewhere it is
// answered PERMISSION_DENIED. Health there describes this process alone, for its probes: LOADING
// until the map is verified, then OK while it serves (a worker: while it hears from its broker).
//
// Reloads (admin requests, SIGHUP in `hscloc serve`) load and verify the map directory on one
// thread (server/reload_coalescer.h); requests keep being served by the old map until the new one
// is ready, and a map that fails to load leaves the old one serving. Stop drains: requests that
// arrive after it are answered UNAVAILABLE, queued and running ones are finished and answered,
// and at most the one running reload is waited for.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "localization/localizer.h"
#include "server/metrics.h"
#include "server/reload_coalescer.h"
#include "server/wire.h"

namespace zmq {
class socket_t;
}  // namespace zmq

namespace hscloc {

struct ServiceOptions {
  std::string bind = "tcp://*:5555";  // port 0 ("tcp://127.0.0.1:0") picks a free port
  // Reload and this process's own Health (its probes) are answered here; keep it on loopback or
  // an ipc:// path, since whoever reaches it may reload the map. Empty: no admin endpoint.
  std::string admin_bind = "tcp://127.0.0.1:5557";
  // Prometheus metrics over HTTP at http://<metrics_bind>/metrics ("host:port", port 0: a free
  // one; server/metrics.h lists them). Empty: counted, not exposed.
  std::string metrics_bind;
  // When set, the service does not bind: it works for the brokers at these endpoints
  // (server/broker.h), announcing its worker count and map to each and heartbeating every
  // heartbeat_interval, and answers each request to the broker it came from. Several brokers, all
  // active, leave no single point of failure: a client that loses one resends to another.
  std::vector<std::string> connect;
  std::chrono::milliseconds heartbeat_interval{500};
  // A worker that has heard nothing from its broker for this many heartbeat intervals is not
  // ready (its Health says so); the broker's heartbeat interval should not be longer.
  int heartbeat_liveness = 4;
  int workers = 0;        // <= 0: one per core
  size_t max_queue = 64;  // waiting Localize requests beyond which OVERLOADED is sent
  size_t max_message_bytes = 64 << 20;
  WireLimits limits;
  LocalizerOptions localizer;
  ComputeDevice device = ComputeDevice::kCpu;
  // CURVE (Z85 keys, 40 characters). Serving on `bind`: the server's secret key turns encryption
  // on; clients must then present one of the allowed public keys (an empty list allows any
  // client with the server's public key), and the admin keys may also reload. Working for
  // brokers (`connect`): this worker's secret key, and the public key of the brokers' backend
  // (the brokers of one deployment share their backend's key pair).
  std::string curve_secret_key;
  std::vector<std::string> curve_allowed_client_keys;
  std::vector<std::string> curve_admin_keys;
  std::string curve_server_key;

  void Check() const;
};

class LocalizationService {
 public:
  // Checks the options; the map is loaded by Start.
  LocalizationService(std::filesystem::path map_dir, const ServiceOptions& options);
  ~LocalizationService();
  LocalizationService(const LocalizationService&) = delete;
  LocalizationService& operator=(const LocalizationService&) = delete;

  // Binds the public and admin endpoints (or connects to the broker), starts the threads, then
  // loads and verifies the map (Health says LOADING meanwhile) and returns the bound public
  // endpoint with its real port (e.g. "tcp://127.0.0.1:41234"), or the broker's endpoint. A
  // worker announces itself to its broker only once the map is verified. Throws
  // std::invalid_argument when an endpoint cannot be bound or the map cannot be loaded.
  std::string Start();
  // Drains and stops; returns when every accepted request is answered. Idempotent.
  void Stop();
  // Loads the map directory again (blocking; coalesced with the admin requests); keeps the old map
  // when the new one fails.
  ReloadOutcome Reload();
  // Reload without waiting for it: the outcome is logged (SIGHUP).
  void RequestReload();

  std::string map_id() const;
  // The admin endpoint as bound (its real port), or empty when there is none.
  const std::string& admin_endpoint() const { return admin_endpoint_; }
  // The metrics' URL as bound (http://host:port/metrics), or empty when they are not exposed.
  std::string metrics_url() const { return metrics_ == nullptr ? "" : metrics_->url(); }
  size_t requests_answered() const { return answered_.load(); }
  // Loads of the map directory so far, the first one included.
  size_t reloads_executed() const;

 private:
  struct Job;
  struct Serving;
  enum class Origin : char;
  struct Readiness {
    wire::Status status;
    std::string reason;
  };

  void OpenSockets();
  void FrontLoop();
  // `broker`: which of the brokers' sockets, for a worker's public requests.
  void ReceiveRequest(Origin origin, size_t broker = 0);
  zmq::socket_t& SocketFor(Origin origin, size_t broker);
  void AnnounceToBrokers();
  void AcceptReload(std::unique_ptr<Job> job, bool admin);
  void AcceptLocalize(std::unique_ptr<Job> job);
  void Reply(const Job& job, const wire::Response& response);
  void PushReply(zmq::socket_t& push, const Job& job, const wire::Response& response);
  void UpdateQueueMetrics();  // with queue_mutex_ held
  void ForwardReply();
  void RefuseLateRequests(zmq::socket_t& socket);
  Readiness CurrentReadiness() const;
  wire::Response HealthReply() const;
  wire::Response InfoReply() const;
  void WorkerLoop(int worker);
  wire::Response Localize(const Job& job, int worker) const;
  std::shared_ptr<const Serving> CurrentServing() const;
  ReloadOutcome LoadMap();

  std::filesystem::path map_dir_;
  ServiceOptions options_;
  int num_workers_ = 1;

  mutable std::mutex serving_mutex_;
  std::shared_ptr<const Serving> serving_;  // null until the first map is verified

  mutable std::mutex queue_mutex_;
  std::condition_variable queue_ready_;
  std::deque<std::unique_ptr<Job>> queue_;
  size_t running_ = 0;

  std::atomic<bool> stopping_{false};
  std::atomic<bool> front_done_{false};
  std::atomic<size_t> answered_{0};
  std::unique_ptr<ServiceMetrics> metrics_;  // before the threads that update it
  std::unique_ptr<struct ZmqState> zmq_;
  std::unique_ptr<ReloadCoalescer> reloader_;
  std::thread front_thread_;
  std::vector<std::thread> workers_;
  std::string endpoint_;
  std::string admin_endpoint_;
  double started_s_ = 0;
  // Per broker, when it was last heard from; front thread only; < 0: never.
  std::vector<double> last_broker_contact_s_;
};

// The id under which a service serves the map bundle in `map_dir`: "<directory name>@<the first
// 16 hex digits of its manifest's SHA-256>", readable, and different for two maps whenever their
// bytes differ (the manifest holds every blob's hash), whatever their directories are called.
std::string MapIdOf(const std::filesystem::path& map_dir);
// The same from the manifest's hash, for a bundle already read.
std::string MapIdOf(const std::filesystem::path& map_dir, const std::string& manifest_sha256);

// A new CURVE key pair in Z85 (40 characters each).
struct CurveKeyPair {
  std::string public_key;
  std::string secret_key;
};
CurveKeyPair GenerateCurveKeyPair();

}  // namespace hscloc
