#include "server/broker.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <deque>
#include <map>
#include <set>
#include <vector>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "proto/hscloc.pb.h"
#include "server/wire.h"
#include "util/check.h"

namespace hscloc {
namespace {

using Clock = std::chrono::steady_clock;

struct Pending {
  uint64_t sequence = 0;
  std::vector<std::string> frames;  // the client's envelope and payload
};

struct Worker {
  int slots = 0;
  int busy = 0;
  Clock::time_point expiry;
};

void SendFrames(zmq::socket_t& socket, const std::vector<std::string>& frames) {
  for (size_t i = 0; i < frames.size(); ++i) {
    socket.send(zmq::buffer(frames[i]),
                i + 1 < frames.size() ? zmq::send_flags::sndmore : zmq::send_flags::none);
  }
}

std::vector<std::string> ReceiveFrames(zmq::socket_t& socket) {
  std::vector<zmq::message_t> messages;
  std::vector<std::string> frames;
  if (!zmq::recv_multipart(socket, std::back_inserter(messages))) return frames;
  for (const zmq::message_t& message : messages) frames.push_back(message.to_string());
  return frames;
}

}  // namespace

struct Broker::State {
  zmq::context_t context{1};
  zmq::socket_t front;
  zmq::socket_t back;
};

void BrokerOptions::Check() const {
  THROW_CHECK_MSG(!front.empty() && !back.empty(), "BrokerOptions: front and back endpoints");
  THROW_CHECK_MSG(max_queue >= 1, "BrokerOptions.max_queue = {}", max_queue);
  THROW_CHECK_MSG(heartbeat_interval.count() > 0 && heartbeat_liveness >= 2,
                  "BrokerOptions: heartbeat interval {} ms, liveness {}",
                  heartbeat_interval.count(), heartbeat_liveness);
}

Broker::Broker(const BrokerOptions& options) : options_(options) { options_.Check(); }

Broker::~Broker() { Stop(); }

std::pair<std::string, std::string> Broker::Start() {
  THROW_CHECK_MSG(state_ == nullptr, "Broker: started twice");
  state_ = std::make_unique<State>();
  state_->front = zmq::socket_t(state_->context, zmq::socket_type::router);
  state_->back = zmq::socket_t(state_->context, zmq::socket_type::router);
  state_->front.set(zmq::sockopt::linger, 1000);
  state_->back.set(zmq::sockopt::linger, 0);
  try {
    state_->front.bind(options_.front);
    state_->back.bind(options_.back);
  } catch (const zmq::error_t& error) {
    ThrowInvalidArgument("broker: cannot bind {} and {}: {}", options_.front, options_.back,
                         error.what());
  }
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
  state_->back.close();
  state_->context.close();
}

void Broker::Loop() {
  std::deque<Pending> queue;
  std::map<std::string, Worker> workers;
  std::map<uint64_t, std::pair<Pending, std::string>> in_flight;  // sequence -> (request, worker)
  uint64_t next_sequence = 0;
  const auto liveness = options_.heartbeat_interval * options_.heartbeat_liveness;
  Clock::time_point next_heartbeat = Clock::now() + options_.heartbeat_interval;

  const auto overloaded = [&](std::vector<std::string> frames) {
    wire::Response response;
    response.set_protocol_version(kProtocolVersion);
    response.set_server_version(kServerVersion);
    response.set_status(wire::OVERLOADED);
    response.set_error_message(
        fmt::format("{} requests wait for a worker; retry later", options_.max_queue));
    frames.back() = response.SerializeAsString();
    SendFrames(state_->front, frames);
  };

  while (!stopping_) {
    zmq::pollitem_t items[] = {{state_->back.handle(), 0, ZMQ_POLLIN, 0},
                               {state_->front.handle(), 0, ZMQ_POLLIN, 0}};
    zmq::poll(items, 2, options_.heartbeat_interval);
    const Clock::time_point now = Clock::now();

    if (items[0].revents & ZMQ_POLLIN) {
      std::vector<std::string> frames = ReceiveFrames(state_->back);
      if (frames.size() >= 2) {
        const std::string& id = frames[0];
        if (frames.size() == 2 && frames[1].rfind(kWorkerReady, 0) == 0) {
          // A worker's announcement, repeated as its heartbeat.
          auto [worker, is_new] = workers.try_emplace(id);
          worker->second.slots =
              std::max(1, std::atoi(frames[1].c_str() + std::strlen(kWorkerReady)));
          worker->second.expiry = now + liveness;
          if (is_new) spdlog::info("broker: worker joined with {} slots", worker->second.slots);
        } else if (frames.size() >= 4) {
          // A reply: worker id, sequence, the client's envelope, payload.
          auto worker = workers.find(id);
          if (worker != workers.end()) {
            worker->second.expiry = now + liveness;
            worker->second.busy = std::max(0, worker->second.busy - 1);
          }
          const uint64_t sequence = std::strtoull(frames[1].c_str(), nullptr, 10);
          if (in_flight.erase(sequence) > 0) {
            SendFrames(state_->front, std::vector<std::string>(frames.begin() + 2, frames.end()));
          }
          // Else a late duplicate of a request already answered by another worker: dropped.
        }
      }
    }

    if (items[1].revents & ZMQ_POLLIN) {
      std::vector<std::string> frames = ReceiveFrames(state_->front);
      if (frames.size() >= 2) {
        if (queue.size() >= options_.max_queue) {
          overloaded(std::move(frames));
        } else {
          queue.push_back({++next_sequence, std::move(frames)});
        }
      }
    }

    // Workers whose heartbeats stopped: their requests go back to the front of the queue.
    for (auto worker = workers.begin(); worker != workers.end();) {
      if (worker->second.expiry >= now) {
        ++worker;
        continue;
      }
      std::vector<Pending> orphans;
      for (auto flight = in_flight.begin(); flight != in_flight.end();) {
        if (flight->second.second == worker->first) {
          orphans.push_back(std::move(flight->second.first));
          flight = in_flight.erase(flight);
        } else {
          ++flight;
        }
      }
      for (auto orphan = orphans.rbegin(); orphan != orphans.rend(); ++orphan) {
        queue.push_front(std::move(*orphan));
      }
      retried_ += orphans.size();
      ++dropped_;
      spdlog::warn("broker: a worker missed its heartbeats; {} of its requests go to others",
                   orphans.size());
      worker = workers.erase(worker);
    }

    // Hand waiting requests to the least busy workers with a free slot.
    while (!queue.empty()) {
      auto best = workers.end();
      for (auto worker = workers.begin(); worker != workers.end(); ++worker) {
        if (worker->second.busy < worker->second.slots &&
            (best == workers.end() || worker->second.busy < best->second.busy)) {
          best = worker;
        }
      }
      if (best == workers.end()) break;
      Pending pending = std::move(queue.front());
      queue.pop_front();
      std::vector<std::string> frames = {best->first, std::to_string(pending.sequence)};
      frames.insert(frames.end(), pending.frames.begin(), pending.frames.end());
      SendFrames(state_->back, frames);
      ++best->second.busy;
      in_flight.emplace(pending.sequence, std::make_pair(std::move(pending), best->first));
    }

    if (now >= next_heartbeat) {
      for (const auto& [id, worker] : workers) SendFrames(state_->back, {id, kHeartbeat});
      next_heartbeat = now + options_.heartbeat_interval;
    }
  }
}

}  // namespace hscloc
