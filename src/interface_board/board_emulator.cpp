#include "interface_board/board_emulator.hpp"

#include <linux/usbdevice_fs.h>
#include <signal.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <umockdev.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "core/error.hpp"
#include "interface_board/usb_protocol.hpp"

namespace pp5::board {

FaultKind faultKindFromName(const std::string& name) { return enumFromName<FaultKind>(name); }

const char* faultKindName(FaultKind k) { return enumName(k).data(); }

Fault parseFault(const std::string& spec) {
  const auto at = spec.find('@');
  if (at == std::string::npos || at == 0 || at + 1 == spec.size())
    throw InputError(fmt::format("board fault '{}': expected KIND@FRAME, e.g. bad_crc@10 or unplug@50:1.5", spec));
  Fault f{faultKindFromName(spec.substr(0, at))};
  std::string rest = spec.substr(at + 1);
  const auto colon = rest.find(':');
  try {
    std::size_t used = 0;
    const unsigned long frame = std::stoul(rest.substr(0, colon), &used);
    if (used != (colon == std::string::npos ? rest.size() : colon)) throw std::invalid_argument("trailing");
    f.frame = static_cast<std::uint32_t>(frame);
    if (colon != std::string::npos) {
      if (f.kind != FaultKind::Unplug) throw std::invalid_argument("only unplug takes seconds");
      f.reconnectAfterS = std::stod(rest.substr(colon + 1), &used);
      if (used != rest.size() - colon - 1 || !(f.reconnectAfterS > 0.0)) throw std::invalid_argument("seconds");
    }
  } catch (const std::logic_error&) {
    throw InputError(fmt::format("board fault '{}': expected KIND@FRAME, or unplug@FRAME:SECONDS with SECONDS > 0",
                                 spec));
  }
  return f;
}

namespace {

using Clock = std::chrono::steady_clock;

// Device, configuration, interface and endpoint descriptors, as sysfs's
// binary "descriptors" file holds them.
std::string descriptorHex(std::uint16_t vid, std::uint16_t pid) {
  const std::uint8_t d[] = {
      // device: USB 2.0, vendor class, ep0 64 bytes, VID, PID, bcdDevice 1.00, no strings, 1 configuration
      18, 1, 0x00, 0x02, 0xff, 0x00, 0x00, 64, static_cast<std::uint8_t>(vid & 0xff),
      static_cast<std::uint8_t>(vid >> 8), static_cast<std::uint8_t>(pid & 0xff), static_cast<std::uint8_t>(pid >> 8),
      0x00, 0x01, 0, 0, 0, 1,
      // configuration 1: 25 bytes in all, 1 interface, bus powered, 100 mA
      9, 2, 25, 0, 1, 1, 0, 0x80, 50,
      // interface 0: 1 endpoint, vendor class
      9, 4, kInterface, 0, 1, 0xff, 0x00, 0x00, 0,
      // bulk IN endpoint, 512-byte packets
      7, 5, kBulkInEndpoint, 0x02, kBulkMaxPacket & 0xff, kBulkMaxPacket >> 8, 0};
  std::string hex;
  for (std::uint8_t b : d) hex += fmt::format("{:02x}", b);
  return hex;
}

struct PendingUrb {
  UMockdevIoctlData* urb = nullptr;  // struct usbdevfs_urb (owns a ref)
  UMockdevIoctlData* buf = nullptr;  // its buffer (a child of urb)
  unsigned long clientAddr = 0;
};

}  // namespace

struct BoardEmulator::Impl {
  std::vector<WireFrame> frames;
  EmulatorOptions opt;
  UMockdevTestbed* testbed = nullptr;
  UMockdevIoctlBase* handler = nullptr;

  mutable std::mutex m;
  EmulatorStats stats;
  // The plugged-in device's node and sysfs path; empty while unplugged.
  std::string devnode, syspath;
  int devnum = 1;
  bool unplugged = false;
  bool gone = false;  // unplugged for good
  // Streaming state.
  bool streaming = false;
  double fps = 30.0;
  Clock::time_point start;
  std::size_t framesStarted = 0;  // since the last Start (for timing)
  std::size_t next = 0;           // next frame to queue
  // Encoded bytes; those before `sent` are gone to the host.
  std::vector<std::uint8_t> bytes;
  std::size_t sent = 0;
  std::size_t pending() const { return bytes.size() - sent; }
  void clearBytes() {
    bytes.clear();
    sent = 0;
  }
  bool halted = false;
  Clock::time_point poweredOn = Clock::now();
  std::vector<bool> faultDone;
  // URBs.
  std::deque<PendingUrb> bulkPending;
  std::deque<PendingUrb> completed;

  void plugIn() {
    devnode = fmt::format("/dev/bus/usb/001/{:03d}", devnum);
    syspath = fmt::format("/devices/pp5board{}", devnum);
    GError* err = nullptr;
    if (!umockdev_testbed_attach_ioctl(testbed, devnode.c_str(), handler, &err)) {
      const std::string msg = err ? err->message : "unknown error";
      if (err) g_error_free(err);
      throw DeviceError(fmt::format("board emulator: cannot attach the ioctl handler to {}: {}", devnode, msg));
    }
    const std::string desc = fmt::format(
        "P: {}\nN: bus/usb/001/{:03d}\nE: SUBSYSTEM=usb\nE: DEVNAME={}\nE: DEVTYPE=usb_device\nE: BUSNUM=001\n"
        "E: DEVNUM={:03d}\nA: busnum=1\\n\nA: devnum={}\\n\nA: speed=480\\n\nA: bConfigurationValue=1\\n\n"
        "H: descriptors={}\n",
        syspath, devnum, devnode, devnum, devnum,
        descriptorHex(opt.vendorId ? opt.vendorId : kDefaultVendorId, opt.productId ? opt.productId : kDefaultProductId));
    if (!umockdev_testbed_add_from_string(testbed, desc.c_str(), &err)) {
      const std::string msg = err ? err->message : "unknown error";
      if (err) g_error_free(err);
      throw DeviceError(fmt::format("board emulator: cannot add the device: {}", msg));
    }
    unplugged = false;
    streaming = false;
    halted = false;
    spdlog::debug("board emulator: plugged in as {}", devnode);
  }

  void unplug() {
    // Requests in flight are given back as the kernel does on a disconnect.
    for (auto& u : bulkPending) finish(u, -ESHUTDOWN, 0);
    bulkPending.clear();
    umockdev_testbed_remove_device(testbed, ("/sys" + syspath).c_str());
    unplugged = true;
    streaming = false;
    ++stats.unplugs;
    ++devnum;  // a reconnected board enumerates at a new address
    spdlog::debug("board emulator: unplugged");
  }

  void finish(PendingUrb& u, int status, int actual) {
    auto* urb = reinterpret_cast<usbdevfs_urb*>(u.urb->data);
    urb->status = status;
    urb->actual_length = actual;
    completed.push_back(u);
    ++stats.urbsCompleted;
  }

  const Fault* faultFor(std::size_t frame, FaultKind kind) const {
    for (std::size_t i = 0; i < opt.faults.size(); ++i)
      if (opt.faults[i].frame == frame && opt.faults[i].kind == kind && !faultDone[i]) return &opt.faults[i];
    return nullptr;
  }
  void markDone(const Fault* f) {
    faultDone[static_cast<std::size_t>(f - opt.faults.data())] = true;
    ++stats.faultsInjected;
  }

  // Queues the frames that are due (an unplug fault unplugs the board here).
  void produce() {
    if (!streaming) return;
    const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
    while (next < frames.size()) {
      if (fps > 0.0 && static_cast<double>(framesStarted) > elapsed * fps) break;
      if (fps <= 0.0 && pending() > (4u << 20)) break;  // as fast as read: keep a few MB ahead
      if (const Fault* f = faultFor(next, FaultKind::Unplug)) {
        if (pending() > 0) break;  // the frames before the unplug get out first
        markDone(f);
        const double after = f->reconnectAfterS;
        unplug();
        if (after > 0.0) {
          g_timeout_add(static_cast<guint>(after * 1000.0), &Impl::reconnectCb, this);
        } else {
          gone = true;
        }
        return;
      }
      if (const Fault* f = faultFor(next, FaultKind::Stall)) {
        markDone(f);
        halted = true;
        return;  // the frame goes out once the host clears the halt
      }
      std::vector<std::uint8_t> enc;
      if (!opt.keepTimestamps)  // the board's own clock: microseconds since it was plugged in
        frames[next].timestampUs = static_cast<std::uint64_t>(
            std::chrono::duration_cast<std::chrono::microseconds>(Clock::now() - poweredOn).count());
      if (next + 1 == frames.size()) frames[next].flags |= kFlagEndOfStream;
      encodeFrame(frames[next], enc);
      const std::size_t payload = enc.size() - kHeaderBytes;
      if (const Fault* f = faultFor(next, FaultKind::BadCrc)) {
        markDone(f);
        enc[kHeaderBytes + payload / 2] ^= 0x5a;
      } else if (const Fault* f = faultFor(next, FaultKind::Drop)) {
        markDone(f);
        const std::size_t at = kHeaderBytes + (payload / 3) / kBulkMaxPacket * kBulkMaxPacket;
        enc.erase(enc.begin() + static_cast<std::ptrdiff_t>(at),
                  enc.begin() + static_cast<std::ptrdiff_t>(std::min(enc.size(), at + kBulkMaxPacket)));
      } else if (const Fault* f = faultFor(next, FaultKind::Short)) {
        markDone(f);
        enc.resize(kHeaderBytes + payload / 2);
      }
      if (sent > 0 && sent >= bytes.size() / 2) {  // drop what was sent, at most once per frame
        bytes.erase(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(sent));
        sent = 0;
      }
      bytes.insert(bytes.end(), enc.begin(), enc.end());
      ++next;
      ++framesStarted;
      ++stats.framesSent;
    }
  }

  // Fills and completes bulk URBs from the queued bytes (or fails them while
  // the endpoint is halted).
  void serveBulk() {
    while (!bulkPending.empty()) {
      PendingUrb u = bulkPending.front();
      if (halted) {
        bulkPending.pop_front();
        finish(u, -EPIPE, 0);
        continue;
      }
      if (pending() == 0) break;
      const std::size_t n = std::min<std::size_t>(pending(), static_cast<std::size_t>(u.buf->data_len));
      std::memcpy(u.buf->data, bytes.data() + sent, n);
      sent += n;
      stats.bytesSent += n;
      bulkPending.pop_front();
      finish(u, 0, static_cast<int>(n));
    }
  }

  // A vendor control request; returns the bytes of data to send back or -errno.
  int control(const std::uint8_t* setup, std::uint8_t* data, int dataLen) {
    const std::uint8_t type = setup[0], req = setup[1];
    const std::uint16_t value = static_cast<std::uint16_t>(setup[2] | (setup[3] << 8));
    if ((type & 0x60) != 0x40) return -EPIPE;  // only vendor requests
    switch (static_cast<Request>(req)) {
      case Request::Start:
        if (!streaming) {
          streaming = true;
          start = Clock::now();
          framesStarted = 0;
        }
        return 0;
      case Request::Stop: streaming = false; return 0;
      case Request::SetFrameRate: fps = value / 100.0; return 0;
      case Request::SetWindow: return 0;  // the emulated scanner always sends whole frames
      case Request::Reset:
        clearBytes();
        return 0;
      case Request::GetStatus: {
        if (dataLen < kStatusBytes) return -EOVERFLOW;
        const std::uint32_t v[8] = {streaming ? 1u : 0u, static_cast<std::uint32_t>(stats.framesSent), 0,
                                    static_cast<std::uint32_t>(fps * 100.0), 0, 0, 0, 0};
        for (int i = 0; i < 8; ++i)
          for (int b = 0; b < 4; ++b) data[4 * i + b] = static_cast<std::uint8_t>(v[i] >> (8 * b));
        return kStatusBytes;
      }
    }
    return -EPIPE;
  }

  static gboolean reconnectCb(gpointer self) {
    auto* impl = static_cast<Impl*>(self);
    std::lock_guard lk(impl->m);
    impl->plugIn();
    ++impl->stats.reconnects;
    return G_SOURCE_REMOVE;
  }

  static gboolean onIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
    return static_cast<Impl*>(self)->handle(client) ? TRUE : FALSE;
  }

  bool handle(UMockdevIoctlClient* client) {
    std::lock_guard lk(m);
    const unsigned long request = umockdev_ioctl_client_get_request(client);
    UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
    // A node whose board was unplugged answers like the kernel: no device,
    // once the requests that were in flight have been given back.
    const bool isReap = request == USBDEVFS_REAPURBNDELAY || request == USBDEVFS_REAPURB;
    if (unplugged || devnode != umockdev_ioctl_client_get_devnode(client)) {
      if (!(isReap && unplugged && !completed.empty())) {
        umockdev_ioctl_client_complete(client, -1, ENODEV);
        return true;
      }
    }
    switch (request) {
      case USBDEVFS_GET_CAPABILITIES: {
        UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(std::uint32_t), nullptr);
        const std::uint32_t caps = USBDEVFS_CAP_ZERO_PACKET | USBDEVFS_CAP_BULK_CONTINUATION |
                                   USBDEVFS_CAP_NO_PACKET_SIZE_LIM | USBDEVFS_CAP_REAP_AFTER_DISCONNECT;
        std::memcpy(d->data, &caps, sizeof caps);
        umockdev_ioctl_client_complete(client, 0, 0);  // before the unref: completing writes `d` back
        umockdev_ioctl_data_unref(d);
        return true;
      }
      case USBDEVFS_CLAIMINTERFACE:
      case USBDEVFS_RELEASEINTERFACE:
      case USBDEVFS_SETINTERFACE:
      case USBDEVFS_SETCONFIGURATION:
      case USBDEVFS_RESETEP:
        umockdev_ioctl_client_complete(client, 0, 0);
        return true;
      case USBDEVFS_RESET:
        clearBytes();
        streaming = false;
        halted = false;
        umockdev_ioctl_client_complete(client, 0, 0);
        return true;
      case USBDEVFS_CLEAR_HALT:
        if (halted) ++stats.stallsCleared;
        halted = false;
        umockdev_ioctl_client_complete(client, 0, 0);
        return true;
      case USBDEVFS_SUBMITURB: {
        PendingUrb u;
        u.urb = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), nullptr);
        auto* urb = reinterpret_cast<usbdevfs_urb*>(u.urb->data);
        u.clientAddr = u.urb->client_addr;
        u.buf = umockdev_ioctl_data_resolve(u.urb, offsetof(usbdevfs_urb, buffer),
                                            static_cast<gsize>(urb->buffer_length), nullptr);
        // The URB keeps its buffer (resolved children live with their parent).
        umockdev_ioctl_data_unref(u.buf);
        if (urb->type == USBDEVFS_URB_TYPE_CONTROL) {
          if (urb->buffer_length < 8) {
            umockdev_ioctl_data_unref(u.urb);
            umockdev_ioctl_client_complete(client, -1, EINVAL);
            return true;
          }
          const int r = control(u.buf->data, u.buf->data + 8, urb->buffer_length - 8);
          finish(u, r < 0 ? r : 0, r < 0 ? 0 : r);
        } else if (urb->type == USBDEVFS_URB_TYPE_BULK && urb->endpoint == kBulkInEndpoint) {
          bulkPending.push_back(u);
        } else {
          umockdev_ioctl_data_unref(u.urb);
          umockdev_ioctl_client_complete(client, -1, EINVAL);
          return true;
        }
        umockdev_ioctl_client_complete(client, 0, 0);
        return true;
      }
      case USBDEVFS_DISCARDURB: {
        // The argument is the URB's address in the client (its value, not a pointer to it).
        unsigned long addr = 0;
        std::memcpy(&addr, arg->data, std::min<std::size_t>(sizeof addr, static_cast<std::size_t>(arg->data_len)));
        auto it = std::find_if(bulkPending.begin(), bulkPending.end(),
                               [&](const PendingUrb& u) { return u.clientAddr == addr; });
        if (it == bulkPending.end()) {
          umockdev_ioctl_client_complete(client, -1, EINVAL);
          return true;
        }
        PendingUrb u = *it;
        bulkPending.erase(it);
        finish(u, -ENOENT, 0);
        umockdev_ioctl_client_complete(client, 0, 0);
        return true;
      }
      case USBDEVFS_REAPURB:
      case USBDEVFS_REAPURBNDELAY: {
        if (completed.empty() && !unplugged) {
          produce();
          if (!unplugged) serveBulk();  // (an unplug just now gave the requests back)
        }
        if (completed.empty()) {
          umockdev_ioctl_client_complete(client, -1, unplugged ? ENODEV : EAGAIN);
          return true;
        }
        PendingUrb u = completed.front();
        completed.pop_front();
        UMockdevIoctlData* ptr = umockdev_ioctl_data_resolve(arg, 0, sizeof(void*), nullptr);
        umockdev_ioctl_data_set_ptr(ptr, 0, u.urb);
        umockdev_ioctl_client_complete(client, 0, 0);  // writes the URB and its buffer back to the client
        umockdev_ioctl_data_unref(ptr);
        umockdev_ioctl_data_unref(u.urb);
        return true;
      }
      default:
        return false;
    }
  }
};

BoardEmulator::BoardEmulator(std::vector<WireFrame> frames, EmulatorOptions options) : impl_(std::make_unique<Impl>()) {
  impl_->frames = std::move(frames);
  for (std::size_t i = 0; i < impl_->frames.size(); ++i) impl_->frames[i].sequence = static_cast<std::uint32_t>(i);
  impl_->opt = std::move(options);
  impl_->fps = impl_->opt.fps;
  impl_->faultDone.assign(impl_->opt.faults.size(), false);
  impl_->testbed = umockdev_testbed_new();
  impl_->handler = umockdev_ioctl_base_new();
  g_signal_connect(impl_->handler, "handle-ioctl", G_CALLBACK(&Impl::onIoctl), impl_.get());
  std::lock_guard lk(impl_->m);
  impl_->plugIn();
}

BoardEmulator::~BoardEmulator() {
  for (auto& u : impl_->bulkPending) umockdev_ioctl_data_unref(u.urb);
  for (auto& u : impl_->completed) umockdev_ioctl_data_unref(u.urb);
  if (impl_->handler) g_object_unref(impl_->handler);
  if (impl_->testbed) g_object_unref(impl_->testbed);
}

EmulatorStats BoardEmulator::stats() const {
  std::lock_guard lk(impl_->m);
  return impl_->stats;
}

namespace {
struct ChildWait {
  GMainLoop* loop;
  int status = 0;
};
void onChildExit(GPid, gint status, gpointer data) {
  auto* w = static_cast<ChildWait*>(data);
  w->status = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  g_main_loop_quit(w->loop);
}
}  // namespace

int BoardEmulator::runChild(const std::vector<std::string>& argv) {
  if (argv.empty()) throw InputError("board emulator: no command to run");
  const char* dir = std::getenv("UMOCKDEV_DIR");
  std::string root = dir ? dir : "";
  if (root.empty()) {
    gchar* r = umockdev_testbed_get_root_dir(impl_->testbed);
    root = r;
    g_free(r);
  }
  std::string preload = "libumockdev-preload.so.0";
  if (const char* p = std::getenv("LD_PRELOAD"); p && *p) preload += std::string(":") + p;

  const pid_t pid = fork();
  if (pid < 0) throw DeviceError(fmt::format("board emulator: fork failed: {}", std::strerror(errno)));
  if (pid == 0) {
    setenv("UMOCKDEV_DIR", root.c_str(), 1);
    setenv("LD_PRELOAD", preload.c_str(), 1);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    execvp(args[0], args.data());
    std::fprintf(stderr, "board emulator: cannot run %s: %s\n", args[0], std::strerror(errno));
    _exit(127);
  }
  ChildWait w{g_main_loop_new(nullptr, FALSE)};
  g_child_watch_add(pid, &onChildExit, &w);
  g_main_loop_run(w.loop);
  g_main_loop_unref(w.loop);
  return w.status;
}

}  // namespace pp5::board
