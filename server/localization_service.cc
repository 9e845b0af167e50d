#include "server/localization_service.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <set>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "server/broker.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {

struct ZmqState {
  zmq::context_t context;
  zmq::socket_t router;
  zmq::socket_t replies;  // workers' replies, for the front thread
  std::string replies_endpoint;
};

struct LocalizationService::Job {
  std::vector<zmq::message_t> envelope;  // routing identity (and a REQ client's empty delimiter)
  wire::Request request;
  Timer received;
};

struct LocalizationService::Serving {
  std::shared_ptr<const Localizer> localizer;
  std::string map_id;
};

namespace {

// The monotonic clock of the service's lifetime (uptime).
double NowSeconds() {
  static const Timer clock;
  return clock.ElapsedSeconds();
}

std::string MapIdOf(const std::filesystem::path& map_dir) {
  const std::filesystem::path canonical = std::filesystem::weakly_canonical(map_dir);
  return canonical.filename().string();
}

std::shared_ptr<const Localizer> LoadLocalizer(const std::filesystem::path& map_dir,
                                               const ServiceOptions& options) {
  return std::make_shared<const Localizer>(
      Localizer::FromBundle(map_dir, options.localizer, options.device));
}

void SendMessage(zmq::socket_t& socket, std::vector<zmq::message_t>& envelope,
                 const std::string& payload) {
  for (zmq::message_t& frame : envelope) {
    socket.send(zmq::message_t(frame.data(), frame.size()), zmq::send_flags::sndmore);
  }
  socket.send(zmq::message_t(payload.data(), payload.size()), zmq::send_flags::none);
}

wire::Response EnvelopeResponse() {
  wire::Response response;
  response.set_protocol_version(kProtocolVersion);
  response.set_server_version(kServerVersion);
  return response;
}

wire::Response ErrorResponse(wire::Status status, const std::string& message) {
  wire::Response response = EnvelopeResponse();
  response.set_status(status);
  response.set_error_message(message);
  return response;
}

// A localize reply that carries `status` both in the envelope and in the localize message.
wire::Response LocalizeErrorResponse(const wire::Request& request, wire::Status status,
                                     const std::string& message) {
  wire::Response response = ErrorResponse(status, message);
  wire::LocalizeResponse* localize = response.mutable_localize();
  localize->set_request_id(request.localize().request_id());
  localize->set_status(status);
  localize->set_error_message(message);
  return response;
}

}  // namespace

void ServiceOptions::Check() const {
  THROW_CHECK_MSG(!bind.empty(), "ServiceOptions.bind is empty");
  THROW_CHECK_MSG(max_queue >= 1, "ServiceOptions.max_queue = {}", max_queue);
  THROW_CHECK_MSG(max_message_bytes >= 1024, "ServiceOptions.max_message_bytes = {}",
                  max_message_bytes);
  THROW_CHECK_MSG(curve_secret_key.empty() || curve_secret_key.size() == 40,
                  "ServiceOptions.curve_secret_key: a Z85 key has 40 characters, not {}",
                  curve_secret_key.size());
  for (const std::string& key : curve_allowed_client_keys) {
    THROW_CHECK_MSG(key.size() == 40,
                    "ServiceOptions.curve_allowed_client_keys: '{}' is no Z85 key", key);
  }
  localizer.Check();
}

LocalizationService::LocalizationService(std::filesystem::path map_dir,
                                         const ServiceOptions& options)
    : map_dir_(std::move(map_dir)), options_(options) {
  options_.Check();
  num_workers_ = ResolveNumThreads(options_.workers);
  auto serving = std::make_shared<Serving>();
  serving->localizer = LoadLocalizer(map_dir_, options_);
  serving->map_id = MapIdOf(map_dir_);
  serving_ = std::move(serving);
}

LocalizationService::~LocalizationService() { Stop(); }

std::shared_ptr<const LocalizationService::Serving> LocalizationService::CurrentServing() const {
  std::lock_guard<std::mutex> lock(serving_mutex_);
  return serving_;
}

std::string LocalizationService::map_id() const { return CurrentServing()->map_id; }

std::string LocalizationService::Start() {
  THROW_CHECK_MSG(zmq_ == nullptr, "LocalizationService: started twice");
  zmq_ = std::make_unique<ZmqState>();
  zmq_->context = zmq::context_t(1);
  if (!options_.curve_secret_key.empty()) {
    // The ZAP handler must be bound before the server socket authenticates anyone.
    zmq::socket_t zap(zmq_->context, zmq::socket_type::rep);
    zap.bind("inproc://zeromq.zap.01");
    zap_thread_ = std::thread([this, socket = std::move(zap)]() mutable {
      std::set<std::string> allowed;
      for (const std::string& key : options_.curve_allowed_client_keys) {
        uint8_t binary[32];
        if (zmq_z85_decode(binary, key.c_str()) != nullptr) {
          allowed.insert(std::string(reinterpret_cast<char*>(binary), 32));
        }
      }
      while (true) {
        std::vector<zmq::message_t> frames;
        try {
          if (!zmq::recv_multipart(socket, std::back_inserter(frames))) continue;
        } catch (const zmq::error_t&) {
          return;  // the context is closing
        }
        if (frames.size() < 7) continue;
        const std::string key = frames[6].to_string();
        const bool ok = allowed.empty() || allowed.count(key) > 0;
        if (!ok) spdlog::warn("refused a client whose CURVE key is not allowed");
        const std::string replies[] = {"1.0",
                                       frames[1].to_string(),
                                       ok ? "200" : "400",
                                       ok ? "OK" : "client key not allowed",
                                       "",
                                       ""};
        for (size_t i = 0; i < 6; ++i) {
          socket.send(zmq::buffer(replies[i]),
                      i + 1 < 6 ? zmq::send_flags::sndmore : zmq::send_flags::none);
        }
      }
    });
  }
  const bool worker_mode = !options_.connect.empty();
  zmq_->router = zmq::socket_t(zmq_->context,
                               worker_mode ? zmq::socket_type::dealer : zmq::socket_type::router);
  // Messages up to twice the limit arrive and are refused with a reply; beyond that ZeroMQ drops
  // them (and the connection) before they take the memory.
  zmq_->router.set(zmq::sockopt::maxmsgsize, static_cast<int64_t>(2 * options_.max_message_bytes));
  zmq_->router.set(zmq::sockopt::linger, 1000);
  if (!worker_mode) {
    // Replies to clients that went away are dropped rather than queued forever.
    zmq_->router.set(zmq::sockopt::router_mandatory, 0);
  }
  if (!options_.curve_secret_key.empty()) {
    zmq_->router.set(zmq::sockopt::curve_server, 1);
    zmq_->router.set(zmq::sockopt::curve_secretkey, options_.curve_secret_key);
  }
  try {
    if (worker_mode) {
      zmq_->router.connect(options_.connect);
    } else {
      zmq_->router.bind(options_.bind);
    }
  } catch (const zmq::error_t& error) {
    ThrowInvalidArgument("cannot {} {}: {}", worker_mode ? "connect to" : "bind",
                         worker_mode ? options_.connect : options_.bind, error.what());
  }
  endpoint_ = worker_mode ? options_.connect : zmq_->router.get(zmq::sockopt::last_endpoint);
  zmq_->replies = zmq::socket_t(zmq_->context, zmq::socket_type::pull);
  zmq_->replies_endpoint = fmt::format("inproc://hscloc-replies-{}", static_cast<void*>(this));
  zmq_->replies.bind(zmq_->replies_endpoint);
  started_s_ = NowSeconds();
  for (int worker = 0; worker < num_workers_; ++worker) {
    workers_.emplace_back([this, worker] { WorkerLoop(worker); });
  }
  front_thread_ = std::thread([this] { FrontLoop(); });
  spdlog::info("serving {} on {} with {} workers (queue {})", map_id(), endpoint_, num_workers_,
               options_.max_queue);
  return endpoint_;
}

void LocalizationService::FrontLoop() {
  std::vector<std::thread> reloads;
  const auto reply = [&](std::vector<zmq::message_t>& envelope, const wire::Response& response) {
    SendMessage(zmq_->router, envelope, response.SerializeAsString());
    ++answered_;
  };
  const bool worker_mode = !options_.connect.empty();
  const std::string ready = fmt::format("{}{}", kWorkerReady, num_workers_);
  auto next_ready = std::chrono::steady_clock::now();
  while (true) {
    if (stopping_) {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      if (queue_.empty() && running_ == 0) break;
    }
    if (worker_mode && !stopping_ && std::chrono::steady_clock::now() >= next_ready) {
      // The announcement doubles as the heartbeat, so a broker that restarted learns of us again.
      zmq_->router.send(zmq::buffer(ready), zmq::send_flags::none);
      next_ready = std::chrono::steady_clock::now() + options_.heartbeat_interval;
    }
    zmq::pollitem_t items[] = {{zmq_->router.handle(), 0, ZMQ_POLLIN, 0},
                               {zmq_->replies.handle(), 0, ZMQ_POLLIN, 0}};
    zmq::poll(items, 2, std::chrono::milliseconds(50));
    if (items[1].revents & ZMQ_POLLIN) {
      std::vector<zmq::message_t> frames;
      if (zmq::recv_multipart(zmq_->replies, std::back_inserter(frames))) {
        for (size_t i = 0; i < frames.size(); ++i) {
          zmq_->router.send(
              frames[i], i + 1 < frames.size() ? zmq::send_flags::sndmore : zmq::send_flags::none);
        }
        ++answered_;
      }
    }
    if (!(items[0].revents & ZMQ_POLLIN)) continue;
    std::vector<zmq::message_t> frames;
    if (!zmq::recv_multipart(zmq_->router, std::back_inserter(frames)) || frames.size() < 2) {
      continue;  // nothing to route a reply to, or the broker's heartbeat
    }
    zmq::message_t payload = std::move(frames.back());
    frames.pop_back();
    auto job = std::make_unique<Job>();
    job->envelope = std::move(frames);
    if (payload.size() > options_.max_message_bytes) {
      reply(job->envelope,
            ErrorResponse(wire::INVALID_REQUEST,
                          fmt::format("message of {} bytes exceeds the server's limit of {}",
                                      payload.size(), options_.max_message_bytes)));
      continue;
    }
    if (!job->request.ParseFromArray(payload.data(), static_cast<int>(payload.size()))) {
      reply(job->envelope, ErrorResponse(wire::INVALID_REQUEST,
                                         "the message is not an hscloc Request (protobuf)"));
      continue;
    }
    const wire::Request& request = job->request;
    if (request.protocol_version() != kProtocolVersion) {
      reply(
          job->envelope,
          ErrorResponse(wire::INVALID_REQUEST,
                        fmt::format("protocol version {}; this server speaks version {} ({})",
                                    request.protocol_version(), kProtocolVersion, kServerVersion)));
      continue;
    }
    const std::shared_ptr<const Serving> serving = CurrentServing();
    switch (request.kind_case()) {
      case wire::Request::kHealth: {
        wire::Response response = EnvelopeResponse();
        response.set_status(stopping_ ? wire::UNAVAILABLE : wire::OK);
        wire::HealthResponse* health = response.mutable_health();
        health->set_status(response.status());
        health->set_map_id(serving->map_id);
        health->set_uptime_s(NowSeconds() - started_s_);
        {
          std::lock_guard<std::mutex> lock(queue_mutex_);
          health->set_queued_requests(static_cast<uint32_t>(queue_.size()));
        }
        reply(job->envelope, response);
        break;
      }
      case wire::Request::kInfo: {
        wire::Response response = EnvelopeResponse();
        response.set_status(wire::OK);
        wire::InfoResponse* info = response.mutable_info();
        const LocalizationMap& map = serving->localizer->map();
        info->set_map_id(serving->map_id);
        info->set_descriptor_dim(static_cast<uint32_t>(map.descriptor_dim()));
        info->set_num_images(static_cast<uint32_t>(map.scene().NumImages()));
        info->set_num_points(map.scene().NumPoints());
        info->set_global_descriptor_dim(static_cast<uint32_t>(map.global_index().dimension()));
        info->set_needs_global_descriptor(!map.vlad().has_value());
        info->set_matcher(MatcherName(options_.localizer.matcher));
        info->set_max_keypoints(options_.limits.max_keypoints);
        info->set_workers(static_cast<uint32_t>(num_workers_));
        reply(job->envelope, response);
        break;
      }
      case wire::Request::kReload: {
        // Loading takes seconds: a thread does it and replies through the workers' channel.
        reloads.emplace_back([this, job = std::move(job)]() mutable {
          const ReloadOutcome outcome = Reload();
          wire::Response response = EnvelopeResponse();
          response.set_status(outcome.success ? wire::OK : wire::INTERNAL);
          wire::ReloadResponse* reload = response.mutable_reload();
          reload->set_status(response.status());
          reload->set_error_message(outcome.error_message);
          reload->set_map_id(outcome.map_id);
          zmq::socket_t push(zmq_->context, zmq::socket_type::push);
          push.connect(zmq_->replies_endpoint);
          SendMessage(push, job->envelope, response.SerializeAsString());
        });
        break;
      }
      case wire::Request::kLocalize: {
        std::unique_lock<std::mutex> lock(queue_mutex_);
        if (stopping_) {
          lock.unlock();
          reply(job->envelope,
                LocalizeErrorResponse(request, wire::UNAVAILABLE, "the server is shutting down"));
        } else if (queue_.size() >= options_.max_queue) {
          lock.unlock();
          reply(job->envelope,
                LocalizeErrorResponse(
                    request, wire::OVERLOADED,
                    fmt::format("{} requests are waiting; retry later", options_.max_queue)));
        } else {
          queue_.push_back(std::move(job));
          lock.unlock();
          queue_ready_.notify_one();
        }
        break;
      }
      default:
        reply(job->envelope, ErrorResponse(wire::INVALID_REQUEST, "the request has no kind"));
    }
  }
  // Requests that reached the socket after the stop are still answered (UNAVAILABLE), until it
  // has been quiet for a moment.
  while (true) {
    zmq::pollitem_t item = {zmq_->router.handle(), 0, ZMQ_POLLIN, 0};
    zmq::poll(&item, 1, std::chrono::milliseconds(100));
    if (!(item.revents & ZMQ_POLLIN)) break;
    std::vector<zmq::message_t> frames;
    if (!zmq::recv_multipart(zmq_->router, std::back_inserter(frames)) || frames.size() < 2) {
      continue;
    }
    wire::Request request;
    request.ParseFromArray(frames.back().data(), static_cast<int>(frames.back().size()));
    frames.pop_back();
    reply(frames,
          request.has_localize()
              ? LocalizeErrorResponse(request, wire::UNAVAILABLE, "the server is shutting down")
              : ErrorResponse(wire::UNAVAILABLE, "the server is shutting down"));
  }
  // The last workers' replies may still be in flight on the inproc channel.
  while (true) {
    zmq::pollitem_t item = {zmq_->replies.handle(), 0, ZMQ_POLLIN, 0};
    zmq::poll(&item, 1, std::chrono::milliseconds(100));
    if (!(item.revents & ZMQ_POLLIN)) break;
    std::vector<zmq::message_t> frames;
    if (!zmq::recv_multipart(zmq_->replies, std::back_inserter(frames))) break;
    for (size_t i = 0; i < frames.size(); ++i) {
      zmq_->router.send(frames[i],
                        i + 1 < frames.size() ? zmq::send_flags::sndmore : zmq::send_flags::none);
    }
    ++answered_;
  }
  for (std::thread& thread : reloads) thread.join();
  front_done_ = true;
}

void LocalizationService::WorkerLoop(int worker) {
  zmq::socket_t push(zmq_->context, zmq::socket_type::push);
  push.connect(zmq_->replies_endpoint);
  while (true) {
    std::unique_ptr<Job> job;
    {
      std::unique_lock<std::mutex> lock(queue_mutex_);
      queue_ready_.wait(lock, [&] { return !queue_.empty() || stopping_; });
      if (queue_.empty()) return;
      job = std::move(queue_.front());
      queue_.pop_front();
      ++running_;
    }
    const wire::LocalizeRequest& request = job->request.localize();
    wire::Response response = EnvelopeResponse();
    wire::LocalizeResponse* localize = response.mutable_localize();
    localize->set_request_id(request.request_id());
    const std::shared_ptr<const Serving> serving = CurrentServing();
    try {
      if (!request.map_id().empty() && request.map_id() != serving->map_id) {
        ThrowInvalidArgument("map '{}' requested, this server serves '{}'", request.map_id(),
                             serving->map_id);
      }
      const LocalizationQuery query = QueryFromWire(request, options_.limits);
      const LocalizerOptions options =
          OptionsFromWire(request.options(), options_.localizer, options_.limits);
      const PoseResult result = serving->localizer->Localize(query, options);
      PoseResultToWire(result, serving->localizer->map().scene(), localize);
      response.set_status(wire::OK);
    } catch (const std::invalid_argument& error) {
      response.set_status(wire::INVALID_REQUEST);
      localize->set_status(wire::INVALID_REQUEST);
      localize->set_error_message(error.what());
    } catch (const std::exception& error) {
      response.set_status(wire::INTERNAL);
      localize->set_status(wire::INTERNAL);
      localize->set_error_message(error.what());
      spdlog::error("request {}: {}", request.request_id(), error.what());
    }
    const double server_ms = job->received.ElapsedMilliseconds();
    localize->mutable_timings()->set_server_ms(server_ms);
    spdlog::info("request {} worker {} {}: {} keypoints, {} inliers, {:.1f} ms{}",
                 request.request_id(), worker, StatusName(localize->status()),
                 request.num_keypoints(), localize->num_inliers(), server_ms,
                 localize->error_message().empty() ? "" : " (" + localize->error_message() + ")");
    SendMessage(push, job->envelope, response.SerializeAsString());
    std::lock_guard<std::mutex> lock(queue_mutex_);
    --running_;
  }
}

void LocalizationService::Stop() {
  if (zmq_ == nullptr || (front_done_ && workers_.empty())) return;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    stopping_ = true;
  }
  queue_ready_.notify_all();
  for (std::thread& worker : workers_) worker.join();
  workers_.clear();
  if (front_thread_.joinable()) front_thread_.join();
  zmq_->router.close();
  zmq_->replies.close();
  zmq_->context.shutdown();
  if (zap_thread_.joinable()) zap_thread_.join();
  zmq_->context.close();
  spdlog::info("stopped after answering {} requests", answered_.load());
}

ReloadOutcome LocalizationService::Reload() {
  std::lock_guard<std::mutex> reload_lock(reload_mutex_);
  ReloadOutcome outcome;
  try {
    auto serving = std::make_shared<Serving>();
    serving->localizer = LoadLocalizer(map_dir_, options_);
    serving->map_id = MapIdOf(map_dir_);
    outcome.map_id = serving->map_id;
    std::lock_guard<std::mutex> lock(serving_mutex_);
    serving_ = std::move(serving);
    outcome.success = true;
    spdlog::info("reloaded map {} from {}", outcome.map_id, map_dir_.string());
  } catch (const std::exception& error) {
    outcome.error_message = error.what();
    outcome.map_id = map_id();
    spdlog::error("reload of {} failed, the previous map keeps serving: {}", map_dir_.string(),
                  error.what());
  }
  return outcome;
}

CurveKeyPair GenerateCurveKeyPair() {
  char public_key[41];
  char secret_key[41];
  if (zmq_curve_keypair(public_key, secret_key) != 0) {
    ThrowInvalidArgument("CURVE key generation failed: libzmq lacks CURVE support");
  }
  return {public_key, secret_key};
}

}  // namespace hscloc
