#include "framework/stream/frame_source.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/io/c3d.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>

namespace soma {

// ---- C3D replay

void C3dReplayOptions::Validate() const {
  if (path.empty()) {
    throw ConfigError(
        "Invalid configuration. source.path = ''. Violated constraint: a C3D "
        "file to replay");
  }
  if (!(speed > 0.0)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. source.speed = {}. Violated constraint: "
        "speed > 0",
        speed));
  }
}

C3dReplaySource::C3dReplaySource(C3dReplayOptions options)
    : options_(std::move(options)) {
  options_.Validate();
}

C3dReplaySource::~C3dReplaySource() = default;

void C3dReplaySource::Open(const std::vector<std::string>&) {
  c3d_ = std::make_unique<C3dData>(ReadC3d(options_.path));
  if (c3d_->num_frames == 0) {
    throw IoError(
        fmt::format("{}: the capture has no frames to replay", options_.path));
  }
  if (options_.realtime && !(c3d_->frame_rate > 0.0)) {
    throw IoError(fmt::format(
        "{}: frame rate {} Hz; a realtime replay needs a positive rate "
        "(source.realtime=false replays as fast as possible)",
        options_.path,
        c3d_->frame_rate));
  }
  outputs_ = ModelOutputColumns(*c3d_);
  if (const auto n = std::count(outputs_.begin(), outputs_.end(), true)) {
    SOMA_LOG(INFO,
             "stream: {} of {}'s {} point columns are model outputs (Plug-in "
             "Gait's angles, forces, virtual points ...): not replayed",
             n,
             options_.path,
             c3d_->num_points);
  }
  end_ = c3d_->num_frames;
  if (options_.max_frames >= 0) end_ = std::min(end_, options_.max_frames);
  next_ = 0;
  start_ = SteadySeconds();
}

double C3dReplaySource::DueTime(int64_t t) const {
  return start_ + static_cast<double>(t) / (c3d_->frame_rate * options_.speed);
}

bool C3dReplaySource::Next(StreamFrame* frame) {
  SOMA_CHECK(c3d_ != nullptr) << "C3dReplaySource: Next() before Open()";
  if (next_ >= end_) return false;
  const int64_t t = next_++;
  if (options_.realtime) {
    const double wait = DueTime(t) - SteadySeconds();
    if (wait > 0) {
      std::this_thread::sleep_for(std::chrono::duration<double>(wait));
    }
    frame->arrival = DueTime(t);
  } else {
    frame->arrival = SteadySeconds();
  }
  frame->number = c3d_->first_frame + t;
  frame->timestamp = c3d_->frame_rate > 0
                         ? static_cast<double>(t) / c3d_->frame_rate
                         : static_cast<double>(t);
  frame->track_ids.clear();
  frame->xyz.clear();
  frame->residuals.clear();
  const int row = static_cast<int>(t);
  for (int k = 0; k < c3d_->num_points; ++k) {
    if (outputs_[k] || !c3d_->valid(row, k)) continue;
    const Eigen::Vector3f p = c3d_->Point(row, k);
    frame->Add(k, p.x(), p.y(), p.z(), c3d_->residuals(row, k));
  }
  return true;
}

bool C3dReplaySource::Ready() {
  if (next_ >= end_) return false;
  return !options_.realtime || DueTime(next_) <= SteadySeconds();
}

double C3dReplaySource::metres_per_unit() const {
  return c3d_->MetresPerUnit();
}

std::string C3dReplaySource::units() const {
  return c3d_->units.empty() ? "mm" : c3d_->units;
}

double C3dReplaySource::frame_rate() const { return c3d_->frame_rate; }

double C3dReplaySource::arrival_rate() const {
  return options_.realtime ? c3d_->frame_rate * options_.speed
                           : c3d_->frame_rate;
}

std::string C3dReplaySource::Describe() const {
  return fmt::format(
      "c3d {} ({})",
      options_.path,
      options_.realtime
          ? fmt::format("replayed at {:g}x its capture rate", options_.speed)
          : std::string("replayed as fast as possible"));
}

C3dReplayOptions DecodeC3dReplayOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  C3dReplayOptions options;
  reader.Require("path", &options.path);
  reader.Read("realtime", &options.realtime);
  reader.Read("speed", &options.speed);
  reader.Read("max_frames", &options.max_frames);
  reader.Check("speed", options.speed > 0, "speed > 0");
  reader.Finish();
  return options;
}

// ---- TCP

void TcpSourceOptions::Validate() const {
  auto fail = [](const std::string& key, auto value, const char* rule) {
    throw ConfigError(fmt::format(
        "Invalid configuration. source.{} = {}. Violated constraint: {}",
        key,
        value,
        rule));
  };
  if (port < 0 || port > 65535) fail("port", port, "0 <= port <= 65535");
  if (!(accept_timeout_s > 0)) {
    fail("accept_timeout_s", accept_timeout_s, "accept_timeout_s > 0");
  }
  if (!(idle_timeout_s > 0)) {
    fail("idle_timeout_s", idle_timeout_s, "idle_timeout_s > 0");
  }
  if (!(frame_rate > 0)) fail("frame_rate", frame_rate, "frame_rate > 0");
}

TcpFrameSource::TcpFrameSource(TcpSourceOptions options)
    : options_(std::move(options)) {
  options_.Validate();
  name_ = fmt::format("tcp {}:{}", options_.host, options_.port);
}

int TcpFrameSource::Listen() {
  if (!listener_.is_open()) {
    listener_ = TcpSocket::Listen(options_.host, options_.port);
    name_ = fmt::format("tcp {}:{}", options_.host, listener_.LocalPort());
  }
  return listener_.LocalPort();
}

void TcpFrameSource::Open(const std::vector<std::string>& labels) {
  Listen();
  SOMA_LOG(INFO,
           "stream: waiting for a client on {} (up to {}s)",
           name_,
           options_.accept_timeout_s);
  client_ = listener_.Accept(options_.accept_timeout_s, name_);
  listener_.Close();  // one client per stream
  const std::vector<uint8_t> hello = EncodeHelloPacket(labels);
  client_.WriteAll(hello, options_.idle_timeout_s, name_);
  SOMA_LOG(INFO, "stream: client connected on {}", name_);
  reader_ = std::thread([this] { ReadLoop(); });
}

TcpFrameSource::~TcpFrameSource() {
  if (reader_.joinable()) {
    client_.Shutdown();  // wakes the reader from its poll
    reader_.join();
  }
}

void TcpFrameSource::ReadLoop() {
  try {
    StreamFrame frame;
    while (ReadOne(&frame)) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (queue_.size() >= kMaxBacklogFrames) {
        throw IoError(fmt::format(
            "{}: {} frames received and not yet labelled; the client sends "
            "faster than frames are labelled (task.backlog=drop keeps up)",
            name_,
            queue_.size()));
      }
      queue_.push_back(std::move(frame));
      frame = StreamFrame{};
      ready_.notify_one();
    }
    std::lock_guard<std::mutex> lock(mutex_);
    ended_ = true;
  } catch (...) {
    std::lock_guard<std::mutex> lock(mutex_);
    error_ = std::current_exception();
  }
  ready_.notify_one();
}

bool TcpFrameSource::Next(StreamFrame* frame) {
  SOMA_CHECK(reader_.joinable()) << "TcpFrameSource: Next() before Open()";
  std::unique_lock<std::mutex> lock(mutex_);
  ready_.wait(lock, [&] { return !queue_.empty() || ended_ || error_; });
  if (!queue_.empty()) {
    *frame = std::move(queue_.front());
    queue_.pop_front();
    return true;
  }
  if (error_) std::rethrow_exception(error_);
  return false;
}

bool TcpFrameSource::ReadOne(StreamFrame* frame) {
  uint8_t header_bytes[kFramePacketHeaderBytes];
  const size_t got =
      client_.ReadFull(header_bytes, options_.idle_timeout_s, name_);
  if (got == 0) return false;  // closed between frames: the end
  if (got < kFramePacketHeaderBytes) {
    throw IoError(fmt::format(
        "{}: the client disconnected mid-frame: {} of the {} header bytes of "
        "the packet after frame {} ({} complete frames kept)",
        name_,
        got,
        kFramePacketHeaderBytes,
        frames_ > 0 ? fmt::format("{}", last_number_) : std::string("none"),
        frames_));
  }
  const FramePacketHeader header = DecodeFramePacketHeader(
      std::span<const uint8_t>(header_bytes, kFramePacketHeaderBytes), name_);
  if (frames_ > 0 && header.number <= last_number_) {
    throw IoError(
        fmt::format("{}: frame number {} after {}: frame numbers must increase",
                    name_,
                    header.number,
                    last_number_));
  }
  buffer_.resize(header.payload_bytes());
  const size_t payload =
      client_.ReadFull(buffer_, options_.idle_timeout_s, name_);
  if (payload < buffer_.size()) {
    throw IoError(fmt::format(
        "{}: the client disconnected mid-frame: frame {} has {} of its {} "
        "point bytes ({} points; {} complete frames kept)",
        name_,
        header.number,
        payload,
        buffer_.size(),
        header.num_points,
        frames_));
  }
  *frame = DecodeFramePayload(header, buffer_, name_);
  frame->arrival = SteadySeconds();
  last_number_ = header.number;
  ++frames_;
  return true;
}

bool TcpFrameSource::Ready() {
  std::lock_guard<std::mutex> lock(mutex_);
  return !queue_.empty();
}

void TcpFrameSource::Reply(const LabelPacket& packet) {
  if (!options_.reply || replies_failed_) return;
  try {
    client_.WriteAll(EncodeLabelPacket(packet), options_.idle_timeout_s, name_);
  } catch (const IoError& e) {
    // A client that closed after its last frame, or stopped reading: its
    // frames still count; labels are no longer sent.
    replies_failed_ = true;
    SOMA_LOG(WARNING,
             "stream: no more label packets to {} ({}); frames are still "
             "read",
             name_,
             e.what());
  }
}

std::string TcpFrameSource::Describe() const { return name_; }

TcpSourceOptions DecodeTcpSourceOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  TcpSourceOptions options;
  reader.Read("host", &options.host);
  reader.Read("port", &options.port);
  reader.Read("accept_timeout_s", &options.accept_timeout_s);
  reader.Read("idle_timeout_s", &options.idle_timeout_s);
  reader.Read("reply", &options.reply);
  reader.Read("frame_rate", &options.frame_rate);
  reader.Check(
      "port", options.port >= 0 && options.port <= 65535, "0 <= port <= 65535");
  reader.Check(
      "accept_timeout_s", options.accept_timeout_s > 0, "accept_timeout_s > 0");
  reader.Check(
      "idle_timeout_s", options.idle_timeout_s > 0, "idle_timeout_s > 0");
  reader.Check("frame_rate", options.frame_rate > 0, "frame_rate > 0");
  reader.Finish();
  return options;
}

// ---- Reference client

FrameClient::FrameClient(const std::string& host, int port, double timeout_s)
    : socket_(TcpSocket::Connect(host, port, timeout_s)),
      timeout_s_(timeout_s) {
  const std::string what = fmt::format("client of {}:{}", host, port);
  std::vector<uint8_t> hello(12);
  if (socket_.ReadFull(hello, timeout_s_, what) < hello.size()) {
    throw IoError(fmt::format("{}: closed before the hello packet", what));
  }
  const uint32_t n = static_cast<uint32_t>(hello[8]) |
                     static_cast<uint32_t>(hello[9]) << 8 |
                     static_cast<uint32_t>(hello[10]) << 16 |
                     static_cast<uint32_t>(hello[11]) << 24;
  if (n > kMaxStreamPoints) {
    throw IoError(fmt::format("{}: hello packet lists {} labels", what, n));
  }
  for (uint32_t i = 0; i < n; ++i) {
    uint8_t length[2];
    if (socket_.ReadFull(length, timeout_s_, what) < 2) {
      throw IoError(fmt::format("{}: hello packet truncated", what));
    }
    hello.insert(hello.end(), length, length + 2);
    std::vector<uint8_t> text(static_cast<size_t>(length[0]) |
                              static_cast<size_t>(length[1]) << 8);
    if (socket_.ReadFull(text, timeout_s_, what) < text.size()) {
      throw IoError(fmt::format("{}: hello packet truncated", what));
    }
    hello.insert(hello.end(), text.begin(), text.end());
  }
  labels_ = DecodeHelloPacket(hello, what);
}

void FrameClient::Send(const StreamFrame& frame) {
  SendBytes(EncodeFramePacket(frame));
}

void FrameClient::SendBytes(std::span<const uint8_t> bytes) {
  socket_.WriteAll(bytes, timeout_s_, "frame client");
}

LabelPacket FrameClient::Receive() {
  std::vector<uint8_t> bytes(kLabelPacketHeaderBytes);
  if (socket_.ReadFull(bytes, timeout_s_, "frame client") < bytes.size()) {
    throw IoError("frame client: the server closed the connection");
  }
  const uint32_t n = DecodeLabelPacketHeader(bytes, "frame client");
  bytes.resize(kLabelPacketHeaderBytes + size_t{n} * kLabelPacketPointBytes);
  const std::span<uint8_t> rest =
      std::span<uint8_t>(bytes).subspan(kLabelPacketHeaderBytes);
  if (socket_.ReadFull(rest, timeout_s_, "frame client") < rest.size()) {
    throw IoError("frame client: label packet truncated");
  }
  return DecodeLabelPacket(bytes, "frame client");
}

// ---- Registry

void RegisterFrameSources() {
  auto& registry = GetRegistry<FrameSource>();
  registry.Register("c3d", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<C3dReplaySource>(DecodeC3dReplayOptions(node));
  });
  registry.Register("tcp", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<TcpFrameSource>(DecodeTcpSourceOptions(node));
  });
}

}  // namespace soma
