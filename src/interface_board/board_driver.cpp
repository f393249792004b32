#include "interface_board/board_driver.hpp"

#include <libusb.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "interface_board/usb_protocol.hpp"

namespace pp5::board {

namespace {
using Clock = std::chrono::steady_clock;

// bmRequestType of the board's commands: vendor, device, host to device.
constexpr std::uint8_t kVendorOut = 0x40;

double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }
}  // namespace

struct BoardDriver::Impl {
  DriverOptions opt;
  std::uint16_t vid = kDefaultVendorId, pid = kDefaultProductId;
  libusb_context* ctx = nullptr;
  libusb_device_handle* handle = nullptr;
  int bus = 0, address = 0;
  std::vector<libusb_transfer*> ring;
  std::vector<std::vector<std::uint8_t>> buffers;
  int inFlight = 0;  // event thread only
  FrameDecoder decoder;
  std::thread events;
  std::atomic<bool> quit{false};
  std::atomic<bool> stopRequested{false};
  bool deviceLost = false;          // event thread only
  bool bytesSinceTimeout = true;    // event thread only
  bool inStall = false;             // event thread only
  bool endOfStream = false;         // event thread only: the board sent its last frame
  bool haveFirstByte = false;
  Clock::time_point firstByte, lastByte;

  mutable std::mutex m;
  std::condition_variable cv;
  std::deque<WireFrame> queue;
  bool ended = false;
  std::string endReason;
  DriverStats stats;
  std::vector<double> latencyUs;  // arrival minus device timestamp

  explicit Impl(DriverOptions o) : opt(std::move(o)), decoder(opt.limits) {
    if (opt.vendorId) vid = opt.vendorId;
    if (opt.productId) pid = opt.productId;
  }

  std::string name() const { return fmt::format("board {:04x}:{:04x}", vid, pid); }

  // Finds and claims the board; false when it is not there.
  bool tryOpen(std::string& why) {
    libusb_device** list = nullptr;
    const ssize_t n = libusb_get_device_list(ctx, &list);
    if (n < 0) {
      why = libusb_strerror(static_cast<int>(n));
      return false;
    }
    libusb_device* found = nullptr;
    for (ssize_t i = 0; i < n; ++i) {
      libusb_device_descriptor d{};
      if (libusb_get_device_descriptor(list[i], &d) == 0 && d.idVendor == vid && d.idProduct == pid) {
        found = list[i];
        break;
      }
    }
    bool ok = false;
    if (!found) {
      why = "not found";
    } else if (const int r = libusb_open(found, &handle); r != 0) {
      why = fmt::format("cannot open it: {}", libusb_strerror(r));
      handle = nullptr;
    } else if (const int c = libusb_claim_interface(handle, kInterface); c != 0) {
      why = fmt::format("cannot claim interface {}: {}", kInterface, libusb_strerror(c));
      libusb_close(handle);
      handle = nullptr;
    } else {
      bus = libusb_get_bus_number(found);
      address = libusb_get_device_address(found);
      ok = true;
    }
    libusb_free_device_list(list, 1);
    return ok;
  }

  void command(Request r, std::uint16_t value, const std::uint8_t* data = nullptr, std::uint16_t len = 0) {
    const int n = libusb_control_transfer(handle, kVendorOut,
                                          static_cast<std::uint8_t>(r), value, 0, const_cast<std::uint8_t*>(data), len,
                                          1000);
    if (n < 0)
      throw DeviceError(fmt::format("{}: control request {} failed: {}", name(), static_cast<int>(r), libusb_strerror(n)));
  }

  void startStreaming() {
    command(Request::Reset, 0);
    if (opt.frameRate > 0.0) command(Request::SetFrameRate, static_cast<std::uint16_t>(std::lround(opt.frameRate * 100.0)));
    if (opt.window[2] > 0) {
      std::uint8_t w[8];
      for (int i = 0; i < 4; ++i) {
        w[2 * i] = static_cast<std::uint8_t>(opt.window[i] & 0xff);
        w[2 * i + 1] = static_cast<std::uint8_t>((opt.window[i] >> 8) & 0xff);
      }
      command(Request::SetWindow, 0, w, 8);
    }
    decoder.reset();
    command(Request::Start, 0);
    for (auto* t : ring) submit(t);
  }

  void submit(libusb_transfer* t) {
    libusb_fill_bulk_transfer(t, handle, kBulkInEndpoint, t->buffer, t->length, &Impl::onTransfer, this,
                              static_cast<unsigned>(opt.transferTimeoutS * 1000.0));
    const int r = libusb_submit_transfer(t);
    if (r == 0) {
      ++inFlight;
    } else {
      ++stats.transferErrors;
      if (r == LIBUSB_ERROR_NO_DEVICE) deviceLost = true;
    }
  }

  void push(WireFrame&& f) {
    const double arrivalUs =
        std::chrono::duration<double, std::micro>(Clock::now().time_since_epoch()).count();
    if (f.flags & kFlagEndOfStream) endOfStream = true;
    std::lock_guard lk(m);
    latencyUs.push_back(arrivalUs - static_cast<double>(f.timestampUs));
    ++stats.frames;
    if (queue.size() >= opt.queueFrames) {
      ++stats.dropped;
      if (!opt.dropOldest) return;  // keep what is queued; this frame is lost
      queue.pop_front();
    }
    queue.push_back(std::move(f));
    cv.notify_one();
  }

  static void LIBUSB_CALL onTransfer(libusb_transfer* t) {
    auto* self = static_cast<Impl*>(t->user_data);
    --self->inFlight;
    self->completed(t);
  }

  void completed(libusb_transfer* t) {
    if (t->actual_length > 0) {
      bytesSinceTimeout = true;
      inStall = false;
      decoder.feed({t->buffer, static_cast<std::size_t>(t->actual_length)}, [&](WireFrame&& f) { push(std::move(f)); });
      std::lock_guard lk(m);
      if (!haveFirstByte) {
        haveFirstByte = true;
        firstByte = Clock::now();
      }
      lastByte = Clock::now();
      stats.bytes += static_cast<std::uint64_t>(t->actual_length);
      stats.decoder = decoder.counters();
    }
    if (quit || stopRequested || endOfStream) return;
    switch (t->status) {
      case LIBUSB_TRANSFER_COMPLETED: break;
      case LIBUSB_TRANSFER_TIMED_OUT:
        if (bytesSinceTimeout) {
          bytesSinceTimeout = false;
          std::lock_guard lk(m);
          ++stats.timeouts;
          spdlog::warn("{}: no data for {:.1f} s", name(), opt.transferTimeoutS);
        }
        break;
      case LIBUSB_TRANSFER_STALL: {
        // Every transfer in flight comes back stalled; clear the halt once
        // per stall (data arriving again ends it).
        if (inStall) break;
        inStall = true;
        const int r = libusb_clear_halt(handle, kBulkInEndpoint);
        std::lock_guard lk(m);
        ++stats.stalls;
        if (r != 0 && r != LIBUSB_ERROR_NOT_FOUND) ++stats.transferErrors;
        break;
      }
      case LIBUSB_TRANSFER_NO_DEVICE:
        deviceLost = true;
        return;
      case LIBUSB_TRANSFER_CANCELLED: return;
      default: {
        std::lock_guard lk(m);
        ++stats.transferErrors;
        break;
      }
    }
    if (!deviceLost) submit(t);
  }

  void finish(const std::string& why) {
    std::lock_guard lk(m);
    if (!ended) {
      ended = true;
      endReason = why;
    }
    cv.notify_all();
  }

  void closeHandle() {
    if (!handle) return;
    libusb_release_interface(handle, kInterface);
    libusb_close(handle);
    handle = nullptr;
  }

  // The USB event loop; also handles losing and finding the board.
  void run() {
    timeval tv{0, 100000};
    while (!quit) {
      libusb_handle_events_timeout_completed(ctx, &tv, nullptr);
      if ((stopRequested || endOfStream) && handle && !deviceLost) {
        // Best effort: the board may already be gone.
        libusb_control_transfer(handle, kVendorOut,
                                static_cast<std::uint8_t>(Request::Stop), 0, 0, nullptr, 0, 500);
        for (auto* t : ring) libusb_cancel_transfer(t);
        while (inFlight > 0) libusb_handle_events_timeout_completed(ctx, &tv, nullptr);
        closeHandle();
        if (endOfStream) spdlog::info("{}: end of stream (the scanner was frozen)", name());
        finish(endOfStream ? "end of stream" : "stopped");
        return;
      }
      if (deviceLost && inFlight == 0) {
        closeHandle();
        {
          std::lock_guard lk(m);
          ++stats.unplugs;
        }
        if (!opt.waitForReconnect) {
          spdlog::warn("{}: unplugged; the stream ends here", name());
          finish("board unplugged");
          return;
        }
        spdlog::warn("{}: unplugged; waiting up to {:.1f} s for it to come back", name(), opt.reconnectTimeoutS);
        const auto lostAt = Clock::now();
        std::string why;
        bool back = false;
        while (!quit && !stopRequested && secondsSince(lostAt) < opt.reconnectTimeoutS) {
          // A fresh context enumerates the bus again: libusb's own device list
          // follows hotplug events, which a board re-enumerated behind an
          // emulator (or a hub that missed the event) does not always give.
          libusb_exit(ctx);
          ctx = nullptr;
          if (libusb_init(&ctx) != 0) {
            ctx = nullptr;
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
            continue;
          }
          if (tryOpen(why)) {
            back = true;
            break;
          }
          std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        if (!back) {
          spdlog::warn("{}: did not come back within {:.1f} s; the stream ends here", name(), opt.reconnectTimeoutS);
          finish("board unplugged");
          return;
        }
        deviceLost = false;
        inStall = false;
        try {
          startStreaming();
        } catch (const DeviceError& e) {
          spdlog::warn("{}", e.what());
          deviceLost = true;
          continue;
        }
        {
          std::lock_guard lk(m);
          ++stats.reconnects;
        }
        spdlog::info("{}: back at bus {} address {}; streaming again", name(), bus, address);
      }
    }
  }
};

BoardDriver::BoardDriver(DriverOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {
  Impl& d = *impl_;
  if (d.opt.transfers < 1 || d.opt.transferBytes < kBulkMaxPacket)
    throw InputError(fmt::format("{}: need at least 1 transfer of at least {} bytes", d.name(), kBulkMaxPacket));
  if (const int r = libusb_init(&d.ctx); r != 0)
    throw DeviceError(fmt::format("libusb cannot start: {}", libusb_strerror(r)));
  const auto t0 = Clock::now();
  std::string why;
  while (!d.tryOpen(why)) {
    if (secondsSince(t0) >= d.opt.openTimeoutS) {
      libusb_exit(d.ctx);
      d.ctx = nullptr;
      throw DeviceError(fmt::format("{}: {} (waited {:.1f} s; is the board plugged in, or the emulator running?)",
                                    d.name(), why, d.opt.openTimeoutS));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  d.buffers.resize(static_cast<std::size_t>(d.opt.transfers));
  for (auto& b : d.buffers) {
    b.resize(static_cast<std::size_t>(d.opt.transferBytes));
    libusb_transfer* t = libusb_alloc_transfer(0);
    t->buffer = b.data();
    t->length = d.opt.transferBytes;
    d.ring.push_back(t);
  }
  try {
    d.startStreaming();
  } catch (...) {
    for (auto* t : d.ring) libusb_cancel_transfer(t);
    d.closeHandle();
    for (auto* t : d.ring) libusb_free_transfer(t);
    libusb_exit(d.ctx);
    throw;
  }
  spdlog::info("{}: streaming at bus {} address {} ({} transfers of {} KiB)", d.name(), d.bus, d.address,
               d.opt.transfers, d.opt.transferBytes / 1024);
  d.events = std::thread([&d] { d.run(); });
}

BoardDriver::~BoardDriver() {
  Impl& d = *impl_;
  d.stopRequested = true;
  if (d.events.joinable()) d.events.join();
  d.quit = true;
  // The event thread has cancelled every transfer and closed the board on its
  // way out (stop, end of stream, or unplugged), so only the memory is left.
  for (auto* t : d.ring) libusb_free_transfer(t);
  if (d.ctx) libusb_exit(d.ctx);
}

bool BoardDriver::next(WireFrame& out, double timeoutS, bool& ended) {
  Impl& d = *impl_;
  std::unique_lock lk(d.m);
  d.cv.wait_for(lk, std::chrono::duration<double>(timeoutS), [&] { return !d.queue.empty() || d.ended; });
  if (!d.queue.empty()) {
    out = std::move(d.queue.front());
    d.queue.pop_front();
    ended = false;
    return true;
  }
  ended = d.ended;
  return false;
}

void BoardDriver::stop() { impl_->stopRequested = true; }

std::string BoardDriver::endReason() const {
  std::lock_guard lk(impl_->m);
  return impl_->endReason;
}

DriverStats BoardDriver::stats() const {
  const Impl& d = *impl_;
  std::lock_guard lk(d.m);
  DriverStats s = d.stats;
  if (d.haveFirstByte) s.seconds = std::chrono::duration<double>(d.lastByte - d.firstByte).count();
  if (!d.latencyUs.empty()) {
    std::vector<double> v = d.latencyUs;
    std::sort(v.begin(), v.end());
    const double base = v.front();
    s.latencyMedianMs = (v[v.size() / 2] - base) / 1000.0;
    s.latencyP95Ms = (v[std::min(v.size() - 1, v.size() * 95 / 100)] - base) / 1000.0;
  }
  return s;
}

std::string jsonFields(const DriverStats& d) {
  const DecoderCounters& c = d.decoder;
  return fmt::format(
      "\"frames\": {}, \"bytes\": {}, \"seconds\": {:.4f}, \"frames_per_s\": {:.3f}, \"mb_per_s\": {:.3f}, "
      "\"dropped\": {}, \"timeouts\": {}, \"stalls\": {}, \"unplugs\": {}, \"reconnects\": {}, "
      "\"transfer_errors\": {}, \"header_crc_errors\": {}, \"payload_crc_errors\": {}, \"bad_headers\": {}, "
      "\"resyncs\": {}, \"skipped_bytes\": {}, \"sequence_gaps\": {}, \"latency_ms_median\": {:.3f}, "
      "\"latency_ms_p95\": {:.3f}",
      d.frames, d.bytes, d.seconds, d.framesPerS(), d.megabytesPerS(), d.dropped, d.timeouts, d.stalls, d.unplugs,
      d.reconnects, d.transferErrors, c.headerCrcErrors, c.payloadCrcErrors, c.badHeaders, c.resyncs, c.skippedBytes,
      c.sequenceGaps, d.latencyMedianMs, d.latencyP95Ms);
}

std::string BoardDriver::describe() const {
  return fmt::format("{} at bus {} address {}", impl_->name(), impl_->bus, impl_->address);
}

}  // namespace pp5::board
