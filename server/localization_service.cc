#include "server/localization_service.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <optional>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "localization/matcher_choice.h"
#include "server/broker.h"
#include "server/curve_auth.h"
#include "server/messages.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {

// Which socket a request came through, and its reply goes back to: the first frame of every
// message on the inproc replies channel.
enum class LocalizationService::Origin : char { kPublic = 'p', kAdmin = 'a' };

struct ZmqState {
  zmq::context_t context;
  std::unique_ptr<CurveAuthenticator> authenticator;
  // The clients' ROUTER, or in worker mode one DEALER per broker (ServiceOptions.connect's order).
  std::vector<zmq::socket_t> publics;
  zmq::socket_t admin;        // the admin endpoint; unbound when there is none
  zmq::socket_t replies;      // workers' and reloads' replies, for the front thread
  zmq::socket_t reload_push;  // used on the reload thread only
  std::string replies_endpoint;
};

struct LocalizationService::Job {
  Origin origin = Origin::kPublic;
  size_t broker = 0;                     // the public socket (a worker's broker) it came through
  std::vector<zmq::message_t> envelope;  // routing identity (and a REQ client's empty delimiter)
  wire::Request request;
  Timer received;
  double queue_seconds = 0;  // from receipt until a worker took it
};

struct LocalizationService::Serving {
  std::shared_ptr<const Localizer> localizer;
  std::string map_id;
};

// A reply travels on the inproc channel behind a frame naming its socket: the origin and, for a
// public request, the index of the public socket (the broker) it came through.
struct ReplyRoute {
  char origin;
  uint8_t socket;
};

namespace {

constexpr char kCurveDomain[] = "clients";

// The monotonic clock of the service's lifetime (uptime).
double NowSeconds() {
  static const Timer clock;
  return clock.ElapsedSeconds();
}

// Whether a request's map id names `map_id`: the whole id, or the directory name before its '@'.
bool NamesMap(const std::string& requested, const std::string& map_id) {
  return requested == map_id || requested == map_id.substr(0, map_id.find('@'));
}

// A worker's socket to the broker at options.connect[index]. Nothing waits in it for a broker
// that is down or not yet up: heartbeats and replies to it are dropped (the broker requeues what
// it gave us when it comes back, and a client resends through another broker), so that no stale
// reply reaches a restarted broker and the front thread never blocks on a dead one.
void ConnectToBroker(zmq::socket_t& socket, const ServiceOptions& options, size_t index) {
  socket.set(zmq::sockopt::immediate, 1);
  socket.set(zmq::sockopt::sndtimeo, 0);
  if (!options.curve_secret_key.empty()) {
    MakeCurveClient(socket, options.curve_server_key, options.curve_secret_key);
  }
  try {
    socket.connect(options.connect[index]);
  } catch (const zmq::error_t& error) {
    ThrowInvalidArgument("cannot connect to {} (--connect): {}", options.connect[index],
                         error.what());
  }
}

// Whether the connection `message` came through authenticated with an admin CURVE key.
bool FromAdminKey(zmq::message_t& message) {
  const char* user = zmq_msg_gets(message.handle(), "User-Id");
  return user != nullptr && std::string(user) == kAdminUserId;
}

}  // namespace

LocalizationService::LocalizationService(std::filesystem::path map_dir,
                                         const ServiceOptions& options)
    : map_dir_(std::move(map_dir)), options_(options) {
  options_.Check();
  num_workers_ = ResolveNumThreads(options_.workers);
  last_broker_contact_s_.assign(options_.connect.size(), -1);
}

LocalizationService::~LocalizationService() { Stop(); }

std::shared_ptr<const LocalizationService::Serving> LocalizationService::CurrentServing() const {
  std::lock_guard<std::mutex> lock(serving_mutex_);
  return serving_;
}

std::string LocalizationService::map_id() const {
  const std::shared_ptr<const Serving> serving = CurrentServing();
  return serving == nullptr ? std::string() : serving->map_id;
}

size_t LocalizationService::reloads_executed() const {
  return reloader_ == nullptr ? 0 : reloader_->reloads_executed();
}

void LocalizationService::OpenSockets() {
  const bool worker_mode = !options_.connect.empty();
  const bool curve = !options_.curve_secret_key.empty();
  if (curve && !worker_mode) {
    // The ZAP handler must be bound before the server socket authenticates anyone.
    zmq_->authenticator = std::make_unique<CurveAuthenticator>(
        zmq_->context, std::vector<CurveDomain>{{kCurveDomain, options_.curve_allowed_client_keys,
                                                 options_.curve_admin_keys}});
  }
  const size_t num_publics = worker_mode ? options_.connect.size() : 1;
  for (size_t index = 0; index < num_publics; ++index) {
    zmq::socket_t& socket = zmq_->publics.emplace_back(
        zmq_->context, worker_mode ? zmq::socket_type::dealer : zmq::socket_type::router);
    // Messages up to twice the limit arrive and are refused with a reply; beyond that ZeroMQ
    // drops them (and the connection) before they take the memory.
    socket.set(zmq::sockopt::maxmsgsize, static_cast<int64_t>(2 * options_.max_message_bytes));
    socket.set(zmq::sockopt::linger, 1000);
    if (worker_mode) {
      ConnectToBroker(socket, options_, index);
    } else {
      // Replies to clients that went away are dropped rather than queued forever.
      socket.set(zmq::sockopt::router_mandatory, 0);
      if (curve) MakeCurveServer(socket, options_.curve_secret_key, kCurveDomain);
      BindOrThrow(socket, options_.bind, "--bind");
    }
  }
  endpoint_ = worker_mode ? fmt::format("{}", fmt::join(options_.connect, ", "))
                          : zmq_->publics[0].get(zmq::sockopt::last_endpoint);
  if (!options_.admin_bind.empty()) {
    zmq_->admin = zmq::socket_t(zmq_->context, zmq::socket_type::router);
    zmq_->admin.set(zmq::sockopt::linger, 1000);
    zmq_->admin.set(zmq::sockopt::router_mandatory, 0);
    BindOrThrow(zmq_->admin, options_.admin_bind, "--admin-bind");
    admin_endpoint_ = zmq_->admin.get(zmq::sockopt::last_endpoint);
  }
  zmq_->replies = zmq::socket_t(zmq_->context, zmq::socket_type::pull);
  zmq_->replies_endpoint = fmt::format("inproc://hscloc-replies-{}", static_cast<void*>(this));
  zmq_->replies.bind(zmq_->replies_endpoint);
  zmq_->reload_push = zmq::socket_t(zmq_->context, zmq::socket_type::push);
  zmq_->reload_push.connect(zmq_->replies_endpoint);
}

std::string LocalizationService::Start() {
  THROW_CHECK_MSG(zmq_ == nullptr, "LocalizationService: started twice");
  metrics_ = std::make_unique<ServiceMetrics>(options_.metrics_bind);
  metrics_->SetWorkers(num_workers_);
  zmq_ = std::make_unique<ZmqState>();
  zmq_->context = zmq::context_t(1);
  try {
    OpenSockets();
  } catch (...) {
    zmq_.reset();
    throw;
  }
  started_s_ = NowSeconds();
  reloader_ = std::make_unique<ReloadCoalescer>([this] { return LoadMap(); });
  for (int worker = 0; worker < num_workers_; ++worker) {
    workers_.emplace_back([this, worker] { WorkerLoop(worker); });
  }
  front_thread_ = std::thread([this] { FrontLoop(); });
  spdlog::info("loading {} (public endpoint {}, admin endpoint {}, metrics {})", map_dir_.string(),
               endpoint_, admin_endpoint_.empty() ? "none" : admin_endpoint_,
               metrics_->url().empty() ? "not exposed" : metrics_->url());
  const ReloadOutcome loaded = reloader_->RequestAndWait();
  if (!loaded.success) {
    Stop();
    ThrowInvalidArgument("{}", loaded.error_message);
  }
  spdlog::info("serving {} on {} with {} workers (queue {})", map_id(), endpoint_, num_workers_,
               options_.max_queue);
  return endpoint_;
}

LocalizationService::Readiness LocalizationService::CurrentReadiness() const {
  if (stopping_) return {wire::UNAVAILABLE, "draining before exit"};
  if (CurrentServing() == nullptr) {
    return {wire::LOADING, fmt::format("loading and verifying the map {}", map_dir_.string())};
  }
  if (options_.connect.empty()) return {wire::OK, ""};
  // Ready while any broker hears from us: the others may be down for a restart.
  const double liveness_s = options_.heartbeat_liveness *
                            std::chrono::duration<double>(options_.heartbeat_interval).count();
  std::vector<std::string> silent;
  for (size_t broker = 0; broker < options_.connect.size(); ++broker) {
    const double contact_s = last_broker_contact_s_[broker];
    if (contact_s >= 0 && NowSeconds() - contact_s <= liveness_s) return {wire::OK, ""};
    silent.push_back(
        contact_s < 0 ? fmt::format("no word yet from the broker at {}", options_.connect[broker])
                      : fmt::format("no word from the broker at {} for {:.1f} s",
                                    options_.connect[broker], NowSeconds() - contact_s));
  }
  const std::string hint =
      options_.curve_secret_key.empty() ? "" : " (is this worker's key on its allow-list?)";
  return {wire::UNAVAILABLE, fmt::format("{}{}", fmt::join(silent, "; "), hint)};
}

wire::Response LocalizationService::HealthReply() const {
  const Readiness readiness = CurrentReadiness();
  wire::Response response = EnvelopeResponse();
  response.set_status(readiness.status);
  wire::HealthResponse* health = response.mutable_health();
  health->set_status(readiness.status);
  health->set_reason(readiness.reason);
  health->set_map_id(map_id());
  health->set_uptime_s(NowSeconds() - started_s_);
  std::lock_guard<std::mutex> lock(queue_mutex_);
  health->set_queued_requests(static_cast<uint32_t>(queue_.size()));
  return response;
}

wire::Response LocalizationService::InfoReply() const {
  const std::shared_ptr<const Serving> serving = CurrentServing();
  if (serving == nullptr) return ErrorResponse(wire::UNAVAILABLE, "the map is still loading");
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
  // The matcher that runs: "auto" resolved for the map being served.
  info->set_matcher(MatcherName(serving->localizer->ResolvedMatcher(options_.localizer.matcher)));
  info->set_max_keypoints(options_.limits.max_keypoints);
  info->set_workers(static_cast<uint32_t>(num_workers_));
  return response;
}

void LocalizationService::Reply(const Job& job, const wire::Response& response) {
  // Counted first, so that a client holding its reply finds it counted.
  metrics_->CountReply(job.request, response.status());
  ++answered_;
  SendReply(SocketFor(job.origin, job.broker), job.envelope, response);
}

zmq::socket_t& LocalizationService::SocketFor(Origin origin, size_t broker) {
  return origin == Origin::kAdmin ? zmq_->admin : zmq_->publics[broker];
}

// Moves one message of the replies channel to the socket its first frame names.
void LocalizationService::ForwardReply() {
  std::vector<zmq::message_t> frames;
  if (!zmq::recv_multipart(zmq_->replies, std::back_inserter(frames)) || frames.empty()) return;
  ReplyRoute route{};
  if (frames.front().size() != sizeof(route)) return;
  std::memcpy(&route, frames.front().data(), sizeof(route));
  frames.erase(frames.begin());
  // Counted first, as in Reply.
  ++answered_;
  const Origin origin = static_cast<Origin>(route.origin);
  if (!SendFrames(SocketFor(origin, route.socket), frames) && origin == Origin::kPublic &&
      !options_.connect.empty()) {
    // The broker's connection is down (it died, or is reconnecting): its client resends.
    spdlog::warn("a reply to the broker at {} was dropped: no connection to it",
                 options_.connect[route.socket]);
  }
}

// Queues a reply on the replies channel (from a worker or the reload thread).
void LocalizationService::PushReply(zmq::socket_t& push, const Job& job,
                                    const wire::Response& response) {
  metrics_->CountReply(job.request, response.status());
  const ReplyRoute route{static_cast<char>(job.origin), static_cast<uint8_t>(job.broker)};
  push.send(zmq::message_t(&route, sizeof(route)), zmq::send_flags::sndmore);
  SendReply(push, job.envelope, response);
}

void LocalizationService::UpdateQueueMetrics() { metrics_->SetQueue(queue_.size(), running_); }

void LocalizationService::AcceptReload(std::unique_ptr<Job> job, bool admin) {
  if (!admin) {
    Reply(*job, RefusalFor(job->request, wire::PERMISSION_DENIED,
                           "Reload is accepted on the admin endpoint (--admin-bind) or from an "
                           "admin CURVE key (--curve-admin-keys)"));
    return;
  }
  // Loading takes seconds: the reload thread replies through the channel when it is done.
  std::shared_ptr<const Job> waiting = std::move(job);
  const bool accepted =
      !stopping_ && reloader_->Request([this, waiting](const ReloadOutcome& done) {
        const wire::Status status = done.cancelled ? wire::UNAVAILABLE
                                    : done.success ? wire::OK
                                                   : wire::INTERNAL;
        wire::Response response = EnvelopeResponse();
        response.set_status(status);
        wire::ReloadResponse* reload = response.mutable_reload();
        reload->set_status(status);
        reload->set_error_message(done.error_message);
        reload->set_map_id(done.map_id);
        PushReply(zmq_->reload_push, *waiting, response);
      });
  if (!accepted) {
    Reply(*waiting, RefusalFor(waiting->request, wire::UNAVAILABLE, "the server is shutting down"));
  }
}

void LocalizationService::AcceptLocalize(std::unique_ptr<Job> job) {
  std::unique_lock<std::mutex> lock(queue_mutex_);
  if (stopping_) {
    lock.unlock();
    Reply(*job, RefusalFor(job->request, wire::UNAVAILABLE, "the server is shutting down"));
  } else if (CurrentServing() == nullptr) {
    lock.unlock();
    Reply(*job, RefusalFor(job->request, wire::UNAVAILABLE, "the map is still loading"));
  } else if (queue_.size() >= options_.max_queue) {
    lock.unlock();
    Reply(*job,
          RefusalFor(job->request, wire::OVERLOADED,
                     fmt::format("{} requests are waiting; retry later", options_.max_queue)));
  } else {
    queue_.push_back(std::move(job));
    UpdateQueueMetrics();
    lock.unlock();
    queue_ready_.notify_one();
  }
}

void LocalizationService::ReceiveRequest(Origin origin, size_t broker) {
  zmq::socket_t& socket = SocketFor(origin, broker);
  std::vector<zmq::message_t> frames;
  if (!zmq::recv_multipart(socket, std::back_inserter(frames))) return;
  if (origin == Origin::kPublic && !options_.connect.empty()) {
    last_broker_contact_s_[broker] = NowSeconds();
  }
  if (frames.size() < 2) return;  // nothing to route a reply to, or the broker's heartbeat
  zmq::message_t payload = std::move(frames.back());
  frames.pop_back();
  auto job = std::make_unique<Job>();
  job->origin = origin;
  job->broker = broker;
  job->envelope = std::move(frames);
  if (payload.size() > options_.max_message_bytes) {
    Reply(*job, ErrorResponse(wire::INVALID_REQUEST,
                              fmt::format("message of {} bytes exceeds the server's limit of {}",
                                          payload.size(), options_.max_message_bytes)));
    return;
  }
  if (!job->request.ParseFromArray(payload.data(), static_cast<int>(payload.size()))) {
    Reply(*job,
          ErrorResponse(wire::INVALID_REQUEST, "the message is not an hscloc Request (protobuf)"));
    return;
  }
  if (job->request.protocol_version() != kProtocolVersion) {
    Reply(*job, ErrorResponse(wire::INVALID_REQUEST,
                              fmt::format("protocol version {}; this server speaks version {} ({})",
                                          job->request.protocol_version(), kProtocolVersion,
                                          kServerVersion)));
    return;
  }
  switch (job->request.kind_case()) {
    case wire::Request::kHealth:
      Reply(*job, HealthReply());
      break;
    case wire::Request::kInfo:
      Reply(*job, InfoReply());
      break;
    case wire::Request::kReload: {
      const bool admin =
          origin == Origin::kAdmin || (!options_.curve_secret_key.empty() && FromAdminKey(payload));
      AcceptReload(std::move(job), admin);
      break;
    }
    case wire::Request::kLocalize:
      AcceptLocalize(std::move(job));
      break;
    default:
      Reply(*job, ErrorResponse(wire::INVALID_REQUEST, "the request has no kind"));
  }
}

// The announcement doubles as the heartbeat, so a broker that restarted learns of us again, and
// names the map served, so that a broker's Health tells which map each worker serves. Never
// blocking: a broker that is down (or refused our key) misses it, and Health goes on answering.
void LocalizationService::AnnounceToBrokers() {
  const std::string ready = fmt::format("{}{} {}", kWorkerReady, num_workers_, map_id());
  for (zmq::socket_t& broker : zmq_->publics) {
    broker.send(zmq::buffer(ready), zmq::send_flags::dontwait);
  }
}

void LocalizationService::FrontLoop() {
  const bool worker_mode = !options_.connect.empty();
  auto next_ready = std::chrono::steady_clock::now();
  while (true) {
    if (stopping_ && reloader_->stopped()) {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      if (queue_.empty() && running_ == 0) break;
    }
    if (worker_mode && !stopping_ && CurrentServing() != nullptr &&
        std::chrono::steady_clock::now() >= next_ready) {
      AnnounceToBrokers();
      next_ready = std::chrono::steady_clock::now() + options_.heartbeat_interval;
    }
    std::vector<zmq::pollitem_t> items = {{zmq_->replies.handle(), 0, ZMQ_POLLIN, 0}};
    for (zmq::socket_t& socket : zmq_->publics)
      items.push_back({socket.handle(), 0, ZMQ_POLLIN, 0});
    if (!admin_endpoint_.empty()) items.push_back({zmq_->admin.handle(), 0, ZMQ_POLLIN, 0});
    zmq::poll(items, std::chrono::milliseconds(50));
    if (items[0].revents & ZMQ_POLLIN) ForwardReply();
    for (size_t index = 0; index < zmq_->publics.size(); ++index) {
      if (items[1 + index].revents & ZMQ_POLLIN) ReceiveRequest(Origin::kPublic, index);
    }
    if (!admin_endpoint_.empty() && (items.back().revents & ZMQ_POLLIN)) {
      ReceiveRequest(Origin::kAdmin);
    }
  }
  for (zmq::socket_t& socket : zmq_->publics) RefuseLateRequests(socket);
  if (!admin_endpoint_.empty()) RefuseLateRequests(zmq_->admin);
  // The last workers' replies may still be in flight on the inproc channel.
  while (true) {
    zmq::pollitem_t item = {zmq_->replies.handle(), 0, ZMQ_POLLIN, 0};
    zmq::poll(&item, 1, std::chrono::milliseconds(100));
    if (!(item.revents & ZMQ_POLLIN)) break;
    ForwardReply();
  }
  front_done_ = true;
}

// Requests that reached `socket` after the stop are still answered (UNAVAILABLE), until it has
// been quiet for a moment.
void LocalizationService::RefuseLateRequests(zmq::socket_t& socket) {
  while (true) {
    zmq::pollitem_t item = {socket.handle(), 0, ZMQ_POLLIN, 0};
    zmq::poll(&item, 1, std::chrono::milliseconds(100));
    if (!(item.revents & ZMQ_POLLIN)) break;
    std::vector<zmq::message_t> frames;
    if (!zmq::recv_multipart(socket, std::back_inserter(frames)) || frames.size() < 2) continue;
    wire::Request request;
    request.ParseFromArray(frames.back().data(), static_cast<int>(frames.back().size()));
    frames.pop_back();
    metrics_->CountReply(request, wire::UNAVAILABLE);
    ++answered_;
    SendReply(socket, frames,
              RefusalFor(request, wire::UNAVAILABLE, "the server is shutting down"));
  }
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
      UpdateQueueMetrics();
    }
    job->queue_seconds = job->received.ElapsedSeconds();
    PushReply(push, *job, Localize(*job, worker));
    std::lock_guard<std::mutex> lock(queue_mutex_);
    --running_;
    UpdateQueueMetrics();
  }
}

wire::Response LocalizationService::Localize(const Job& job, int worker) const {
  const wire::LocalizeRequest& request = job.request.localize();
  wire::Response response = EnvelopeResponse();
  wire::LocalizeResponse* localize = response.mutable_localize();
  localize->set_request_id(request.request_id());
  const std::shared_ptr<const Serving> serving = CurrentServing();
  localize->set_map_id(serving->map_id);
  std::optional<StageTimings> timings;
  try {
    if (!request.map_id().empty() && !NamesMap(request.map_id(), serving->map_id)) {
      ThrowInvalidArgument("map '{}' requested, this server serves '{}'", request.map_id(),
                           serving->map_id);
    }
    const LocalizationQuery query = QueryFromWire(request, options_.limits);
    const LocalizerOptions options =
        OptionsFromWire(request.options(), options_.localizer, options_.limits);
    const PoseResult result = serving->localizer->Localize(query, options);
    timings = result.timings;
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
  const double server_ms = job.received.ElapsedMilliseconds();
  localize->mutable_timings()->set_server_ms(server_ms);
  if (timings) {
    metrics_->ObserveLocalize(*timings, localize->num_inliers(), job.queue_seconds,
                              server_ms * 1e-3);
  }
  spdlog::info("request {} worker {} {}: {} keypoints, {} inliers, {:.1f} ms{}",
               request.request_id(), worker, StatusName(localize->status()),
               request.num_keypoints(), localize->num_inliers(), server_ms,
               localize->error_message().empty() ? "" : " (" + localize->error_message() + ")");
  return response;
}

void LocalizationService::Stop() {
  if (zmq_ == nullptr || (front_done_ && workers_.empty())) return;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    stopping_ = true;
  }
  queue_ready_.notify_all();
  // At most the running reload is waited for; the waiting ones are answered UNAVAILABLE.
  reloader_->Stop();
  for (std::thread& worker : workers_) worker.join();
  workers_.clear();
  if (front_thread_.joinable()) front_thread_.join();
  for (zmq::socket_t& socket : zmq_->publics) socket.close();
  zmq_->admin.close();
  zmq_->replies.close();
  zmq_->reload_push.close();
  zmq_->authenticator.reset();
  zmq_->context.close();
  spdlog::info("stopped after answering {} requests", answered_.load());
}

ReloadOutcome LocalizationService::Reload() {
  THROW_CHECK_MSG(reloader_ != nullptr, "LocalizationService: Reload before Start");
  return reloader_->RequestAndWait();
}

void LocalizationService::RequestReload() {
  THROW_CHECK_MSG(reloader_ != nullptr, "LocalizationService: Reload before Start");
  reloader_->Request([](const ReloadOutcome&) {});  // LoadMap logs the outcome
}

ReloadOutcome LocalizationService::LoadMap() {
  ReloadOutcome outcome;
  const Timer load_time;
  try {
    // A link to the map (turned to roll an update) is resolved once, so that the bundle loaded
    // and the name in its id are the same; the hash is that of the manifest as loaded.
    const std::filesystem::path bundle = std::filesystem::weakly_canonical(map_dir_);
    auto serving = std::make_shared<Serving>();
    serving->localizer = std::make_shared<const Localizer>(
        Localizer::FromBundle(bundle, options_.localizer, options_.device));
    serving->map_id = MapIdOf(bundle, serving->localizer->map().manifest_sha256());
    outcome.map_id = serving->map_id;
    std::lock_guard<std::mutex> lock(serving_mutex_);
    serving_ = std::move(serving);
    outcome.success = true;
    metrics_->SetMap(outcome.map_id, load_time.ElapsedSeconds());
    spdlog::info("loaded and verified map {} from {} in {:.2f} s; {}", outcome.map_id,
                 map_dir_.string(), load_time.ElapsedSeconds(),
                 DescribeMatcher(*serving_->localizer, options_.localizer.matcher));
  } catch (const std::exception& error) {
    outcome.error_message = error.what();
    outcome.map_id = map_id();
    spdlog::error("loading {} failed{}: {}", map_dir_.string(),
                  outcome.map_id.empty() ? "" : ", the previous map keeps serving", error.what());
  }
  metrics_->CountMapLoad(outcome.success);
  return outcome;
}

}  // namespace hscloc
