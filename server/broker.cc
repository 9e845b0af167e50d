#include "server/broker.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <deque>
#include <map>
#include <random>
#include <set>
#include <vector>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "proto/hscloc.pb.h"
#include "server/curve_auth.h"
#include "server/messages.h"
#include "server/wire.h"
#include "util/check.h"
#include "util/timer.h"

namespace hscloc {
namespace {

struct Pending {
  uint64_t sequence = 0;
  std::vector<std::string> frames;  // the client's envelope and payload
};

struct Worker {
  int slots = 0;
  int busy = 0;
  std::string map_id;  // as its last announcement named it
  std::chrono::steady_clock::time_point expiry;
};

constexpr char kClientDomain[] = "clients";
constexpr char kWorkerDomain[] = "workers";

double NowSeconds() {
  static const Timer clock;
  return clock.ElapsedSeconds();
}

}  // namespace

struct Broker::State {
  zmq::context_t context{1};
  std::unique_ptr<CurveAuthenticator> authenticator;
  zmq::socket_t front;
  zmq::socket_t back;
  // The back's connection events: a worker process that dies closes its connection, and the
  // broker then asks which worker is gone at once instead of waiting out its heartbeats.
  zmq::socket_t back_monitor;
  zmq::socket_t admin;
  std::chrono::steady_clock::time_point probe_until;  // a connection closed: probe until then
  // Routing, touched by the loop's thread only.
  std::deque<Pending> queue;
  std::map<std::string, Worker> workers;
  std::map<uint64_t, std::pair<Pending, std::string>> in_flight;  // sequence -> (request, worker)
  uint64_t next_sequence = 0;
  // Prefixes every sequence sent to a worker: a reply that a worker addressed to an earlier run
  // of this broker (same endpoint, counter started again) is never taken for one of ours.
  std::string incarnation;
};

void BrokerOptions::Check() const {
  THROW_CHECK_MSG(!front.empty() && !back.empty(), "BrokerOptions: front and back endpoints");
  THROW_CHECK_MSG(max_queue >= 1, "BrokerOptions.max_queue = {}", max_queue);
  THROW_CHECK_MSG(heartbeat_interval.count() > 0 && heartbeat_liveness >= 2,
                  "BrokerOptions: heartbeat interval {} ms, liveness {}",
                  heartbeat_interval.count(), heartbeat_liveness);
  if (!curve_secret_key.empty()) {
    CheckCurveKey(curve_secret_key, "BrokerOptions.curve_secret_key (--curve-secret-key)");
  }
  for (const std::string& key : curve_allowed_client_keys) {
    CheckCurveKey(key, "BrokerOptions.curve_allowed_client_keys (--curve-allowed-keys)");
  }
  THROW_CHECK_MSG(!curve_secret_key.empty() || curve_allowed_client_keys.empty(),
                  "BrokerOptions.curve_allowed_client_keys (--curve-allowed-keys) need the "
                  "front's CURVE key (--curve-secret-key)");
  if (!backend_curve_secret_key.empty()) {
    CheckCurveKey(backend_curve_secret_key,
                  "BrokerOptions.backend_curve_secret_key (--backend-curve-secret-key)");
  }
  for (const std::string& key : curve_allowed_worker_keys) {
    CheckCurveKey(key, "BrokerOptions.curve_allowed_worker_keys (--curve-allowed-worker-keys)");
  }
  THROW_CHECK_MSG(backend_curve_secret_key.empty() == curve_allowed_worker_keys.empty(),
                  "BrokerOptions.backend_curve_secret_key and curve_allowed_worker_keys "
                  "(--backend-curve-secret-key, --curve-allowed-worker-keys) go together: the "
                  "back admits only the workers whose keys are listed");
}

Broker::Broker(const BrokerOptions& options) : options_(options) { options_.Check(); }

Broker::~Broker() { Stop(); }

void Broker::OpenSockets() {
  std::vector<CurveDomain> domains;
  if (!options_.curve_secret_key.empty()) {
    domains.push_back({kClientDomain, options_.curve_allowed_client_keys, {}});
  }
  if (!options_.backend_curve_secret_key.empty()) {
    domains.push_back({kWorkerDomain, options_.curve_allowed_worker_keys, {}});
  }
  // The ZAP handler must be bound before the server sockets authenticate anyone.
  if (!domains.empty()) {
    state_->authenticator = std::make_unique<CurveAuthenticator>(state_->context, domains);
  }
  state_->front = zmq::socket_t(state_->context, zmq::socket_type::router);
  state_->back = zmq::socket_t(state_->context, zmq::socket_type::router);
  state_->front.set(zmq::sockopt::linger, 1000);
  state_->back.set(zmq::sockopt::linger, 0);
  if (!options_.curve_secret_key.empty()) {
    MakeCurveServer(state_->front, options_.curve_secret_key, kClientDomain);
  }
  if (!options_.backend_curve_secret_key.empty()) {
    MakeCurveServer(state_->back, options_.backend_curve_secret_key, kWorkerDomain);
  }
  // A send to a worker whose connection is gone fails (EHOSTUNREACH) instead of vanishing.
  state_->back.set(zmq::sockopt::router_mandatory, 1);
  const std::string monitor_endpoint =
      fmt::format("inproc://hscloc-broker-back-{}", static_cast<void*>(this));
  if (zmq_socket_monitor(state_->back.handle(), monitor_endpoint.c_str(), ZMQ_EVENT_DISCONNECTED) !=
      0) {
    ThrowInvalidArgument("broker: cannot monitor the workers' connections");
  }
  state_->back_monitor = zmq::socket_t(state_->context, zmq::socket_type::pair);
  state_->back_monitor.connect(monitor_endpoint);
  BindOrThrow(state_->front, options_.front, "--bind");
  BindOrThrow(state_->back, options_.back, "--backend");
  if (options_.admin_bind.empty()) return;
  state_->admin = zmq::socket_t(state_->context, zmq::socket_type::router);
  state_->admin.set(zmq::sockopt::linger, 0);
  BindOrThrow(state_->admin, options_.admin_bind, "--admin-bind");
  admin_endpoint_ = state_->admin.get(zmq::sockopt::last_endpoint);
}

std::pair<std::string, std::string> Broker::Start() {
  THROW_CHECK_MSG(state_ == nullptr, "Broker: started twice");
  metrics_ = std::make_unique<BrokerMetrics>(options_.metrics_bind);
  state_ = std::make_unique<State>();
  try {
    OpenSockets();
  } catch (...) {
    state_.reset();
    throw;
  }
  started_s_ = NowSeconds();
  state_->incarnation =
      fmt::format("{:016x}:", std::random_device()() * 0x100000000ull ^ std::random_device()());
  const std::string front = state_->front.get(zmq::sockopt::last_endpoint);
  const std::string back = state_->back.get(zmq::sockopt::last_endpoint);
  thread_ = std::thread([this] { Loop(); });
  spdlog::info("broker: clients on {}, workers on {}", front, back);
  return {front, back};
}

void Broker::Stop() {
  if (state_ == nullptr || stopping_.exchange(true)) return;
  if (thread_.joinable()) thread_.join();
  state_->front.close();
  // Monitoring stops before its socket closes: libzmq's I/O thread would block on an event sent
  // to a closed monitor, and the context's termination with it.
  zmq_socket_monitor(state_->back.handle(), nullptr, 0);
  state_->back_monitor.close();
  state_->back.close();
  state_->admin.close();
  state_->authenticator.reset();
  state_->context.close();
}

// The broker's own Health (ready with at least one worker); any other request is refused, since
// the broker holds no map: reload each worker on its own admin endpoint.
void Broker::AnswerAdmin() {
  const size_t workers = state_->workers.size();
  std::vector<zmq::message_t> frames;
  if (!zmq::recv_multipart(state_->admin, std::back_inserter(frames)) || frames.size() < 2) return;
  wire::Request request;
  const bool parsed =
      request.ParseFromArray(frames.back().data(), static_cast<int>(frames.back().size()));
  frames.pop_back();
  if (!parsed || !request.has_health()) {
    SendReply(state_->admin, frames,
              RefusalFor(request, wire::INVALID_REQUEST,
                         "a broker answers Health only; reload each worker on its admin endpoint"));
    return;
  }
  wire::Response response = EnvelopeResponse();
  const wire::Status status = workers > 0 ? wire::OK : wire::UNAVAILABLE;
  response.set_status(status);
  wire::HealthResponse* health = response.mutable_health();
  health->set_status(status);
  health->set_workers(static_cast<uint32_t>(workers));
  health->set_uptime_s(NowSeconds() - started_s_);
  for (const auto& [id, worker] : state_->workers) {
    wire::WorkerStatus* status = health->add_worker_status();
    status->set_map_id(worker.map_id);
    status->set_slots(static_cast<uint32_t>(worker.slots));
    status->set_busy(static_cast<uint32_t>(worker.busy));
  }
  if (workers == 0)
    health->set_reason("no worker has joined the broker (or all missed heartbeats)");
  SendReply(state_->admin, frames, response);
}

void Broker::Loop() {
  Clock::time_point next_heartbeat = Clock::now() + options_.heartbeat_interval;
  while (!stopping_) {
    std::vector<zmq::pollitem_t> items = {{state_->back.handle(), 0, ZMQ_POLLIN, 0},
                                          {state_->front.handle(), 0, ZMQ_POLLIN, 0},
                                          {state_->back_monitor.handle(), 0, ZMQ_POLLIN, 0}};
    if (!admin_endpoint_.empty()) items.push_back({state_->admin.handle(), 0, ZMQ_POLLIN, 0});
    const bool probing = Clock::now() < state_->probe_until;
    zmq::poll(items, probing ? kProbeInterval : options_.heartbeat_interval);
    const Clock::time_point now = Clock::now();
    if (items.size() > 3 && (items[3].revents & ZMQ_POLLIN)) AnswerAdmin();
    if (items[2].revents & ZMQ_POLLIN) NoteClosedConnection(now);
    if (items[0].revents & ZMQ_POLLIN) ReceiveFromWorker(now);
    if (items[1].revents & ZMQ_POLLIN) ReceiveFromClient();
    if (probing || now >= next_heartbeat) {
      // The heartbeat is also the probe: a send to a worker whose connection is gone fails.
      for (const auto& [id, worker] : state_->workers) SendToWorker({id, kHeartbeat});
      if (now >= next_heartbeat) next_heartbeat = now + options_.heartbeat_interval;
    }
    RequeueSilentWorkers(now);
    DispatchWaiting();
    PublishGauges();
  }
}

// A connection on the back closed; which worker's it was shows when a send to it fails, once
// ZeroMQ has torn down its pipe, so the workers are probed for a while.
void Broker::NoteClosedConnection(Clock::time_point now) {
  std::vector<zmq::message_t> event;
  if (!zmq::recv_multipart(state_->back_monitor, std::back_inserter(event))) return;
  state_->probe_until = now + options_.heartbeat_interval;
}

bool Broker::SendToWorker(const std::vector<std::string>& frames) {
  try {
    SendFrames(state_->back, frames);
    return true;
  } catch (const zmq::error_t& error) {
    if (error.num() != EHOSTUNREACH) throw;
    // Its connection is gone: dropped in this round, its requests handed to others.
    auto worker = state_->workers.find(frames[0]);
    if (worker != state_->workers.end()) {
      worker->second.expiry = Clock::time_point::min();
      spdlog::warn("broker: a worker's connection closed");
    }
    return false;
  }
}

void Broker::ReceiveFromWorker(Clock::time_point now) {
  const std::vector<std::string> frames = ReceiveFrames(state_->back);
  if (frames.size() < 2) return;
  const std::string& id = frames[0];
  const auto liveness = options_.heartbeat_interval * options_.heartbeat_liveness;
  if (frames.size() == 2 && frames[1].rfind(kWorkerReady, 0) == 0) {
    // A worker's announcement, repeated as its heartbeat: "READY<slots> <map id>".
    auto [worker, is_new] = state_->workers.try_emplace(id);
    const char* slots = frames[1].c_str() + std::strlen(kWorkerReady);
    worker->second.slots = std::max(1, std::atoi(slots));
    const size_t space = frames[1].find(' ');
    const std::string map_id = space == std::string::npos ? "" : frames[1].substr(space + 1);
    if (!is_new && map_id != worker->second.map_id) {
      spdlog::info("broker: a worker now serves {} (was {})", map_id, worker->second.map_id);
    }
    worker->second.map_id = map_id;
    worker->second.expiry = now + liveness;
    if (is_new) {
      spdlog::info("broker: worker joined with {} slots, serving {}", worker->second.slots, map_id);
      metrics_->CountWorkerJoined();
      ++joined_;
    }
  } else if (frames.size() >= 4) {
    // A reply: worker id, sequence, the client's envelope, payload.
    auto worker = state_->workers.find(id);
    if (worker != state_->workers.end()) {
      worker->second.expiry = now + liveness;
      worker->second.busy = std::max(0, worker->second.busy - 1);
    }
    const std::string& incarnation = state_->incarnation;
    const bool ours = frames[1].compare(0, incarnation.size(), incarnation) == 0;
    const uint64_t sequence =
        ours ? std::strtoull(frames[1].c_str() + incarnation.size(), nullptr, 10) : 0;
    if (ours && state_->in_flight.erase(sequence) > 0) {
      metrics_->CountAnswered();
      SendFrames(state_->front, std::vector<std::string>(frames.begin() + 2, frames.end()));
    }
    // Else a late duplicate of a request already answered by another worker, or a reply meant
    // for an earlier run of this broker: dropped.
  }
}

void Broker::ReceiveFromClient() {
  std::vector<std::string> frames = ReceiveFrames(state_->front);
  if (frames.size() < 2) return;
  if (state_->queue.size() < options_.max_queue) {
    state_->queue.push_back({++state_->next_sequence, std::move(frames)});
    return;
  }
  frames.back() =
      ErrorResponse(wire::OVERLOADED,
                    fmt::format("{} requests wait for a worker; retry later", options_.max_queue))
          .SerializeAsString();
  metrics_->CountOverloaded();
  SendFrames(state_->front, frames);
}

// Workers whose heartbeats stopped: their requests go back to the front of the queue.
void Broker::RequeueSilentWorkers(Clock::time_point now) {
  for (auto worker = state_->workers.begin(); worker != state_->workers.end();) {
    if (worker->second.expiry >= now && worker->second.slots > 0) {
      ++worker;
      continue;
    }
    std::vector<Pending> orphans;
    for (auto flight = state_->in_flight.begin(); flight != state_->in_flight.end();) {
      if (flight->second.second == worker->first) {
        orphans.push_back(std::move(flight->second.first));
        flight = state_->in_flight.erase(flight);
      } else {
        ++flight;
      }
    }
    for (auto orphan = orphans.rbegin(); orphan != orphans.rend(); ++orphan) {
      state_->queue.push_front(std::move(*orphan));
    }
    retried_ += orphans.size();
    ++dropped_;
    metrics_->CountWorkerDropped(orphans.size());
    spdlog::warn("broker: a worker missed its heartbeats; {} of its requests go to others",
                 orphans.size());
    worker = state_->workers.erase(worker);
  }
}

// Hands waiting requests to the least busy workers with a free slot.
void Broker::DispatchWaiting() {
  std::map<std::string, Worker>& workers = state_->workers;
  while (!state_->queue.empty()) {
    auto best = workers.end();
    for (auto worker = workers.begin(); worker != workers.end(); ++worker) {
      if (worker->second.busy < worker->second.slots &&
          (best == workers.end() || worker->second.busy < best->second.busy)) {
        best = worker;
      }
    }
    if (best == workers.end()) return;
    std::vector<std::string> frames = {
        best->first, state_->incarnation + std::to_string(state_->queue.front().sequence)};
    frames.insert(frames.end(), state_->queue.front().frames.begin(),
                  state_->queue.front().frames.end());
    if (!SendToWorker(frames)) {
      // Gone: no more slots there; the request waits for the next worker.
      best->second.slots = 0;
      continue;
    }
    Pending pending = std::move(state_->queue.front());
    state_->queue.pop_front();
    ++best->second.busy;
    state_->in_flight.emplace(pending.sequence, std::make_pair(std::move(pending), best->first));
  }
}

void Broker::PublishGauges() {
  size_t slots = 0;
  for (const auto& [id, worker] : state_->workers) slots += static_cast<size_t>(worker.slots);
  metrics_->SetWorkers(state_->workers.size(), slots);
  std::map<std::string, size_t> maps;
  for (const auto& [id, worker] : state_->workers) ++maps[worker.map_id];
  metrics_->SetWorkerMaps(maps);
  metrics_->SetQueue(state_->queue.size(), state_->in_flight.size());
}

}  // namespace hscloc
