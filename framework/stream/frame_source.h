// Where `soma stream` gets its frames: a C3D take replayed at its capture
// rate (or as fast as possible), or a TCP client speaking the frame protocol
// of frame_protocol.h. Sources are built from config through the
// `frame_source` registry (`name: c3d` / `name: tcp`).
#pragma once

#include "framework/config/node.h"
#include "framework/stream/frame.h"
#include "framework/stream/frame_protocol.h"
#include "framework/stream/socket.h"

#include <condition_variable>
#include <deque>
#include <exception>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

namespace soma {

struct C3dData;

/// A stream of raw frames.
class FrameSource {
 public:
  static constexpr std::string_view kRegistryName = "frame_source";
  virtual ~FrameSource() = default;

  /// Opens the source (reads the file; listens and accepts a client, sending
  /// it the hello packet with `labels`, the label names of the ids in the
  /// replies). IoError if it cannot.
  virtual void Open(const std::vector<std::string>& labels) = 0;
  /// Waits for the next complete frame (sets StreamFrame::arrival). Returns
  /// false at the end of the stream (a C3D that ends, a client that closed
  /// between frames). IoError on malformed data, a client that disconnects
  /// inside a frame or goes silent past its timeout.
  virtual bool Next(StreamFrame* frame) = 0;
  /// True if the frame after the last one returned is already waiting (the
  /// backlog, for the drop policy).
  virtual bool Ready() = 0;
  /// Sends the labels of a frame back (TCP with replies on); else nothing.
  /// A client that no longer takes them (closed, or not reading within the
  /// idle timeout) is logged once and sent nothing more; its frames count.
  virtual void Reply(const LabelPacket& packet) { (void)packet; }

  /// Metres per unit of the frames' coordinates.
  virtual double metres_per_unit() const = 0;
  /// The unit string written to output C3D files ("mm", ...).
  virtual std::string units() const = 0;
  /// Nominal capture rate, Hz (written to output files).
  virtual double frame_rate() const = 0;
  /// Rate at which frames arrive, Hz (a replay at speed s: s x the capture
  /// rate); one frame period is the default latency budget.
  virtual double arrival_rate() const { return frame_rate(); }
  /// For messages: "c3d take.c3d (realtime)", "tcp 127.0.0.1:7301".
  virtual std::string Describe() const = 0;
};

/// Options of C3dReplaySource.
struct C3dReplayOptions {
  std::string path;         // the take
  bool realtime = true;     // at its capture rate; false: as fast as possible
  double speed = 1.0;       // realtime: playback speed factor (> 0)
  int64_t max_frames = -1;  // stop after this many frames (-1: all)
  void Validate() const;    // ConfigError on violation
};

/// Replays a C3D file: frame t is due at start + t / (rate * speed) and its
/// arrival is that due time (realtime), or now (as fast as possible). Points
/// keep the file's units; track ids are the column indices (a column is a
/// trajectory). Columns that are model outputs (ModelOutputColumns of
/// io/c3d.h: Plug-in Gait's angles, forces, virtual points) are not replayed:
/// no camera system streams them.
class C3dReplaySource : public FrameSource {
 public:
  explicit C3dReplaySource(C3dReplayOptions options);
  ~C3dReplaySource() override;

  void Open(const std::vector<std::string>& labels) override;
  bool Next(StreamFrame* frame) override;
  bool Ready() override;
  double metres_per_unit() const override;
  std::string units() const override;
  double frame_rate() const override;
  double arrival_rate() const override;
  std::string Describe() const override;

 private:
  C3dReplayOptions options_;
  std::unique_ptr<C3dData> c3d_;
  std::vector<bool> outputs_;  // per column: a model output, not replayed
  int64_t next_ = 0;           // the next frame to return
  int64_t end_ = 0;
  double start_ = 0.0;  // steady seconds of frame 0's due time
  double DueTime(int64_t t) const;
};

/// Options of TcpFrameSource.
struct TcpSourceOptions {
  std::string host = "127.0.0.1";
  int port = 7301;               // 0: an ephemeral port (logged)
  double accept_timeout_s = 60;  // waiting for the client
  double idle_timeout_s = 10;    // no byte for this long: IoError
  bool reply = true;             // send a label packet per frame
  double frame_rate = 120;       // Hz, the rate written to output files
  void Validate() const;         // ConfigError on violation
};

/// Accepts one client and reads frame packets from it (frame_protocol.h) on
/// a reader thread, which stamps each frame's arrival when its last byte is
/// in: a frame waiting while earlier ones are labelled counts the wait in its
/// latency, and Ready() sees complete frames. The reader's error (malformed
/// packet, disconnect mid-frame, silence) reaches Next() after the complete
/// frames before it. Coordinates are millimetres.
class TcpFrameSource : public FrameSource {
 public:
  /// Most frames received and not yet taken by Next() (catch_up backlog).
  static constexpr size_t kMaxBacklogFrames = 100000;

  explicit TcpFrameSource(TcpSourceOptions options);
  ~TcpFrameSource() override;

  /// Starts listening (Open() calls it if needed); returns the bound port.
  int Listen();
  void Open(const std::vector<std::string>& labels) override;
  bool Next(StreamFrame* frame) override;
  bool Ready() override;
  void Reply(const LabelPacket& packet) override;
  double metres_per_unit() const override { return 0.001; }
  std::string units() const override { return "mm"; }
  double frame_rate() const override { return options_.frame_rate; }
  std::string Describe() const override;

 private:
  TcpSourceOptions options_;
  TcpSocket listener_;
  TcpSocket client_;
  std::string name_;
  int64_t frames_ = 0;
  int64_t last_number_ = 0;
  bool replies_failed_ = false;  // the client stopped taking label packets
  std::vector<uint8_t> buffer_;  // reader thread only

  bool ReadOne(StreamFrame* frame);  // on the reader thread
  void ReadLoop();
  std::thread reader_;
  std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<StreamFrame> queue_;  // complete frames not yet taken
  bool ended_ = false;             // the client closed between frames
  std::exception_ptr error_;       // the reader's error
};

/// Decoders (unknown keys are an error).
C3dReplayOptions DecodeC3dReplayOptions(const ConfigNode& node);
TcpSourceOptions DecodeTcpSourceOptions(const ConfigNode& node);

/// A reference client of the frame protocol (used by the tests; a template
/// for a capture system's bridge): connects, reads the hello, sends frames
/// and reads label packets.
class FrameClient {
 public:
  /// Connects and reads the hello packet; IoError on failure.
  FrameClient(const std::string& host, int port, double timeout_s = 10);

  /// The server's label names (ids of the label packets).
  const std::vector<std::string>& labels() const { return labels_; }
  /// Sends one frame packet (coordinates in millimetres).
  void Send(const StreamFrame& frame);
  /// Sends raw bytes (tests: malformed or partial packets).
  void SendBytes(std::span<const uint8_t> bytes);
  /// Reads the next label packet; IoError on timeout or a bad packet.
  LabelPacket Receive();
  /// Closes the connection (ends the stream).
  void Close() { socket_.Close(); }

 private:
  TcpSocket socket_;
  double timeout_s_;
  std::vector<std::string> labels_;
};

/// Registers `c3d` and `tcp` in the frame_source registry.
void RegisterFrameSources();

}  // namespace soma
