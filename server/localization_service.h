// The localization service: a ZeroMQ ROUTER socket in front of a pool of worker threads that share
// one read-only map (DESIGN.md, "Serving and scale").
//
// The front thread owns the ROUTER socket. It decodes each request envelope, answers Health and
// Info at once (so probes answer under load), refuses what it cannot decode, and queues Localize
// requests for the workers, answering OVERLOADED when the bounded queue is full. Workers localize
// against the map they find when they start a request and hand their reply back to the front
// thread, which alone writes to the ROUTER socket. Every request gets exactly one reply.
//
// Reload (an admin request, or SIGHUP in `hscloc serve`) loads and verifies the map directory again
// in the background; requests keep being served by the old map until the new one is ready, and a
// map that fails to load leaves the old one serving. Stop drains: requests that arrive after it are
// answered UNAVAILABLE, queued and running ones are finished and answered.
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
#include "server/reload_coalescer.h"
#include "server/wire.h"

namespace hscloc {

struct ServiceOptions {
  std::string bind = "tcp://*:5555";  // port 0 ("tcp://127.0.0.1:0") picks a free port
  // When set, the service does not bind: it works for the broker at this endpoint
  // (server/broker.h), announcing its worker count and heartbeating every heartbeat_interval.
  std::string connect;
  std::chrono::milliseconds heartbeat_interval{500};
  int workers = 0;        // <= 0: one per core
  size_t max_queue = 64;  // waiting Localize requests beyond which OVERLOADED is sent
  size_t max_message_bytes = 64 << 20;
  WireLimits limits;
  LocalizerOptions localizer;
  ComputeDevice device = ComputeDevice::kCpu;
  // CURVE: the server's secret key (Z85, 40 characters) turns encryption on; clients must then
  // present one of the allowed public keys (Z85); an empty list allows any client with the
  // server's public key.
  std::string curve_secret_key;
  std::vector<std::string> curve_allowed_client_keys;

  void Check() const;
};

class LocalizationService {
 public:
  // Loads and verifies the map; throws std::invalid_argument when it cannot.
  LocalizationService(std::filesystem::path map_dir, const ServiceOptions& options);
  ~LocalizationService();
  LocalizationService(const LocalizationService&) = delete;
  LocalizationService& operator=(const LocalizationService&) = delete;

  // Binds (or connects to the broker) and starts the front thread and the workers; returns the
  // bound endpoint with its real port (e.g. "tcp://127.0.0.1:41234"), or the broker's endpoint.
  // Throws when the endpoint cannot be bound.
  std::string Start();
  // Drains and stops; returns when every accepted request is answered. Idempotent.
  void Stop();
  // Loads the map directory again (blocking); keeps the old map when the new one fails.
  ReloadOutcome Reload();

  std::string map_id() const;
  size_t requests_answered() const { return answered_.load(); }

 private:
  struct Job;
  struct Serving;

  void FrontLoop();
  void WorkerLoop(int worker);
  std::shared_ptr<const Serving> CurrentServing() const;
  void ZapLoop();

  std::filesystem::path map_dir_;
  ServiceOptions options_;
  int num_workers_ = 1;

  mutable std::mutex serving_mutex_;
  std::shared_ptr<const Serving> serving_;
  std::mutex reload_mutex_;

  std::mutex queue_mutex_;
  std::condition_variable queue_ready_;
  std::deque<std::unique_ptr<Job>> queue_;
  size_t running_ = 0;

  std::atomic<bool> stopping_{false};
  std::atomic<bool> front_done_{false};
  std::atomic<size_t> answered_{0};
  std::atomic<uint64_t> reply_channel_{0};
  std::unique_ptr<struct ZmqState> zmq_;
  std::thread front_thread_;
  std::thread zap_thread_;
  std::vector<std::thread> workers_;
  std::string endpoint_;
  double started_s_ = 0;
};

// A new CURVE key pair in Z85 (40 characters each).
struct CurveKeyPair {
  std::string public_key;
  std::string secret_key;
};
CurveKeyPair GenerateCurveKeyPair();

}  // namespace hscloc
