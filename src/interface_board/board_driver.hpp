#pragma once
// The interface board's driver, on libusb-1.0.
//
// It finds the board by vendor and product id, claims its interface, starts
// streaming, and keeps a ring of asynchronous bulk IN transfers in flight.
// A USB event thread decodes the bytes as they complete (the only copy of a
// frame's pixels is the decoder's, into the frame's own buffer) and hands
// whole frames to a bounded queue. When the consumer is slow the queue drops
// by policy and counts; the event thread never waits for the consumer.
//
// Faults: a transfer timeout is counted and the transfer resubmitted; a stall
// is cleared and streaming goes on; when the board is unplugged the driver
// either ends the stream cleanly or waits for the board to come back (at any
// address: it re-enumerates by vendor and product id), as configured.
#include <cstdint>
#include <memory>
#include <string>

#include "interface_board/wire.hpp"

namespace pp5::board {

struct DriverOptions {
  std::uint16_t vendorId = 0, productId = 0;  // 0 = the defaults of usb_protocol.hpp
  int transferBytes = 256 * 1024;  // bytes per bulk transfer
  int transfers = 8;               // transfers kept in flight
  std::size_t queueFrames = 32;    // decoded frames waiting for the consumer
  bool dropOldest = true;          // when the queue is full: drop the oldest (else the newest) frame
  double frameRate = 0.0;          // > 0: ask the board for this rate (SetFrameRate)
  int window[4] = {0, 0, 0, 0};    // x, y, w, h; w > 0: ask the board for this capture window
  double openTimeoutS = 5.0;       // wait this long for the board to appear at start
  double transferTimeoutS = 2.0;   // a transfer with no data for this long counts as a timeout
  bool waitForReconnect = false;   // unplugged: wait for the board (else end the stream)
  double reconnectTimeoutS = 10.0; // ... for this long, then end the stream
  DecoderLimits limits;
};

struct DriverStats {
  std::uint64_t frames = 0;      // decoded and queued
  std::uint64_t bytes = 0;       // received on the bulk endpoint
  std::uint64_t dropped = 0;     // dropped by the queue's policy (the consumer was slow)
  std::uint64_t timeouts = 0, stalls = 0, unplugs = 0, reconnects = 0, transferErrors = 0;
  DecoderCounters decoder;       // CRC errors, resyncs, gaps, ...
  double seconds = 0.0;          // from the first byte to the last
  double framesPerS() const { return seconds > 0.0 ? static_cast<double>(frames) / seconds : 0.0; }
  double megabytesPerS() const { return seconds > 0.0 ? static_cast<double>(bytes) / seconds / 1e6 : 0.0; }
  // Arrival time minus the device timestamp, less the smallest such value
  // seen (the two clocks are not synchronised, so the fastest frame defines 0).
  double latencyMedianMs = 0.0, latencyP95Ms = 0.0;
};

// The counters as JSON object members (no braces), for summary.json and
// `pp5echo board-stats`: "frames": N, "bytes": N, ... "latency_ms_p95": X.
std::string jsonFields(const DriverStats& s);

class BoardDriver {
public:
  // Opens the board (waiting up to openTimeoutS) and starts streaming.
  // DeviceError, naming the vendor and product id, when it never appears or
  // cannot be claimed.
  explicit BoardDriver(DriverOptions options);
  ~BoardDriver();  // stops the board and the event thread
  BoardDriver(const BoardDriver&) = delete;
  BoardDriver& operator=(const BoardDriver&) = delete;

  // The next frame, waiting up to timeoutS. Returns false on a timeout with
  // `ended` false, or once the stream has ended (unplugged with no reconnect,
  // or stop()) and every queued frame was taken, with `ended` true.
  bool next(WireFrame& out, double timeoutS, bool& ended);
  // Ends the stream: the board is told to stop; frames already queued stay.
  void stop();
  // Why the stream ended ("" while it runs): e.g. "board unplugged".
  std::string endReason() const;

  DriverStats stats() const;
  std::string describe() const;  // "board 1209:0001 at bus 1 address 2"

  struct Impl;

private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace pp5::board
