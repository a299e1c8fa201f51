// The USB transport and backend through real libusb against an emulated bridge: umockdev's testbed
// provides the sysfs entries and /dev/bus/usb nodes libusb enumerates, and its ioctl emulation
// hands every usbdevfs ioctl on the node (SUBMITURB, REAPURB, DISCARDURB, CLAIMINTERFACE, ...) to
// FakeBridge below, which answers the control requests and bulk transfers as drivers/usb/README.md
// specifies. libusb and UsbTransport run unmodified: enumeration by vid:pid:serial, claiming,
// string descriptors, control transfers, bulk OUT and IN, timeouts (DISCARDURB), stalls and
// unplugging (ENODEV) all go through the real code paths.
//
// umockdev needs libumockdev-preload in LD_PRELOAD. Each test re-runs itself (this binary, with
// --gtest_filter=the test) with the preload; the re-run's exit status is the test's result. The
// test is skipped only when the preload cannot be loaded (umockdev not installed).
#include <gtest/gtest.h>

#include <dlfcn.h>
#include <link.h>
#include <linux/usbdevice_fs.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <unistd.h>
#include <umockdev.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "drivers/backends.h"
#include "drivers/link.h"
#include "drivers/position_word.h"
#include "drivers/usb/transport.h"
#include "drivers/usb/usb_backend.h"

using namespace idm::drivers;
using namespace idm::drivers::usb;

#if defined(__SANITIZE_THREAD__)
// ThreadSanitizer, in this binary only: umockdev's testbed runs a GLib worker thread, and GLib, not
// built for ThreadSanitizer, hands memory and mutexes between that thread and the caller through
// its own futex-based GMutex, which ThreadSanitizer cannot see. The two reports this gives lie
// wholly inside umockdev and GLib (Debian 12: umockdev 0.17.16, GLib 2.74.6): a GRecMutex that the
// worker clears after the caller's last unlock (umockdev_ioctl_base_unregister_path), and a path
// string that the caller frees after the worker copied it (g_strdup). Nothing of this file's or
// the driver's own code is in either stack.
extern "C" const char* __tsan_default_suppressions() {
  return "race:g_rec_mutex_clear\nrace:g_strdup\n";
}
#endif

namespace {

constexpr const char* kPreload = "libumockdev-preload.so.0";
constexpr const char* kChildEnv = "IDM_UMOCKDEV_CHILD";
constexpr int kNoUmockdev = 77;

bool preload_active() { return dlopen(kPreload, RTLD_LAZY | RTLD_NOLOAD) != nullptr; }

// The sanitizer runtime this binary loaded as a shared library (GCC's AddressSanitizer and
// ThreadSanitizer), or "". It must stay first in LD_PRELOAD, ahead of the umockdev preload, or it
// refuses to start (its interceptors must come first).
std::string sanitizer_runtime() {
  std::string found;
  dl_iterate_phdr(
      [](dl_phdr_info* info, std::size_t, void* out) {
        const std::string name = info->dlpi_name ? info->dlpi_name : "";
        const std::string base = name.substr(name.rfind('/') + 1);
        if (base.rfind("libasan.so", 0) == 0 || base.rfind("libtsan.so", 0) == 0) {
          *static_cast<std::string*>(out) = name;
          return 1;
        }
        return 0;
      },
      &found);
  return found;
}

enum class Run { Here, Done, NoUmockdev };

// In the parent: re-runs the current test in a child with the preload and reports its outcome
// (Done, or NoUmockdev when the preload could not be loaded). In the child: Here (run the body).
Run run_under_umockdev() {
  if (std::getenv(kChildEnv) != nullptr) {
    if (!preload_active()) {
      std::fprintf(stderr, "umockdev: %s could not be preloaded\n", kPreload);
      std::fflush(stderr);
      std::_Exit(kNoUmockdev);
    }
    return Run::Here;
  }
  const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string filter =
      std::string("--gtest_filter=") + info->test_suite_name() + "." + info->name();
  std::fflush(stdout);
  std::fflush(stderr);
  const pid_t pid = fork();
  if (pid == 0) {
    std::string preload = kPreload;
    if (const std::string runtime = sanitizer_runtime(); !runtime.empty())
      preload = runtime + ":" + preload;
    if (const char* old = std::getenv("LD_PRELOAD"); old && *old) preload += std::string(":") + old;
    setenv("LD_PRELOAD", preload.c_str(), 1);
    setenv(kChildEnv, "1", 1);
    char exe[4096];
    const ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n <= 0) std::_Exit(126);
    exe[n] = '\0';
    execl(exe, exe, filter.c_str(), static_cast<char*>(nullptr));
    std::_Exit(127);
  }
  int status = 0;
  EXPECT_EQ(waitpid(pid, &status, 0), pid);
  if (WIFEXITED(status) && WEXITSTATUS(status) == kNoUmockdev) return Run::NoUmockdev;
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
      << "the test under umockdev failed (its output is above); wait status " << status;
  return Run::Done;
}

#define IDM_UNDER_UMOCKDEV()                                                               \
  switch (run_under_umockdev()) {                                                          \
    case Run::Here:                                                                        \
      break;                                                                               \
    case Run::NoUmockdev:                                                                  \
      /* ./idm test installs umockdev, so a preload that fails is a broken set-up, not a */ \
      /* reason to pass: the test fails and says what to install. */                        \
      FAIL() << "umockdev is not usable here: " << kPreload                                 \
             << " cannot be preloaded (install the Debian package umockdev)";              \
    case Run::Done:                                                                        \
      return;                                                                              \
  }

// ---- the emulated bridge ----

std::string hex(const std::vector<std::uint8_t>& bytes) {
  static const char* digits = "0123456789ABCDEF";
  std::string out;
  for (std::uint8_t b : bytes) {
    out += digits[b >> 4];
    out += digits[b & 15];
  }
  return out;
}

// Device descriptor (1209:4944, strings 1..3, serial = 3), one configuration with interface 0
// (vendor class) and bulk endpoints 0x01 OUT and 0x81 IN.
std::vector<std::uint8_t> descriptors() {
  return {0x12, 0x01, 0x00, 0x02, 0x00, 0x00, 0x00, 0x40, 0x09, 0x12, 0x44, 0x49, 0x00,
          0x01, 0x01, 0x02, 0x03, 0x01,                                      // device
          0x09, 0x02, 0x20, 0x00, 0x01, 0x01, 0x00, 0x80, 0x32,              // configuration
          0x09, 0x04, 0x00, 0x00, 0x02, 0xFF, 0x00, 0x00, 0x00,              // interface 0
          0x07, 0x05, 0x01, 0x02, 0x00, 0x02, 0x00,                          // bulk OUT 0x01
          0x07, 0x05, 0x81, 0x02, 0x00, 0x02, 0x00};                         // bulk IN 0x81
}

struct Urb {
  UMockdevIoctlData* urb = nullptr;     // our reference; the struct usbdevfs_urb
  UMockdevIoctlData* buffer = nullptr;  // borrowed from urb
  usbdevfs_urb* get() const { return reinterpret_cast<usbdevfs_urb*>(urb->data); }
};

// One bridge behind one /dev/bus/usb node. Its handler runs on umockdev's worker thread; the
// test reads the recorded state under the mutex.
class FakeBridge {
 public:
  FakeBridge(std::string serial, int devnum) : serial_(std::move(serial)), devnum_(devnum) {
    info_.dac_bits = 16;
    info_.position_word_bits = 32;
    info_.tick_hz = 1000000;
    info_.max_dac_rate_hz = 1000000;
    info_.buffer_capacity_samples = 65536;
    info_.max_position_rate_hz = 200000;
    handler_ = umockdev_ioctl_base_new();
    g_signal_connect(handler_, "handle-ioctl", G_CALLBACK(&FakeBridge::on_ioctl), this);
  }
  ~FakeBridge() {
    for (Urb& u : in_flight_) g_object_unref(u.urb);
    for (Urb& u : done_) g_object_unref(u.urb);
    g_object_unref(handler_);
  }

  std::string devnode() const {
    char text[64];
    std::snprintf(text, sizeof text, "/dev/bus/usb/001/%03d", devnum_);
    return text;
  }
  std::string record() const {
    const std::string d = hex(descriptors());
    char num[8];
    std::snprintf(num, sizeof num, "%03d", devnum_);
    return "P: /devices/pci0000:00/0000:00:14.0/usb1/1-" + std::to_string(devnum_) +
           "\nN: bus/usb/001/" + num + "=" + d + "\nE: DEVNAME=" + devnode() +
           "\nE: DEVTYPE=usb_device\nE: DRIVER=usb\nE: SUBSYSTEM=usb\nE: BUSNUM=001\nE: DEVNUM=" +
           num + "\nA: busnum=1\nA: devnum=" + std::to_string(devnum_) +
           "\nA: idVendor=1209\nA: idProduct=4944\nA: serial=" + serial_ +
           "\nA: speed=480\nA: bConfigurationValue=1\nA: bNumConfigurations=1\nH: descriptors=" +
           d + "\n\n";
  }
  UMockdevIoctlBase* handler() const { return handler_; }

  // Fault injection.
  void unplug() { std::lock_guard lock(mutex_); unplugged_ = true; }
  void replug() { std::lock_guard lock(mutex_); unplugged_ = false; }
  // Switched off and on: back at once with its clock and its count started over, unconfigured.
  void power_cycle() {
    std::lock_guard lock(mutex_);
    unplugged_ = false;
    power_up_ = std::chrono::steady_clock::now();
    position_ = 0;
    status_ = {};
  }
  void set_claim_busy(bool busy) { std::lock_guard lock(mutex_); claim_busy_ = busy; }
  void set_mute_bulk_in(bool mute) { std::lock_guard lock(mutex_); mute_in_ = mute; }
  void set_has_latch(bool has) { std::lock_guard lock(mutex_); has_latch_ = has; }
  void set_position(std::int64_t count) { std::lock_guard lock(mutex_); position_ = count; }

  // What the bridge saw.
  std::vector<std::int32_t> codes() const { std::lock_guard lock(mutex_); return codes_; }
  BridgeConfig config() const { std::lock_guard lock(mutex_); return config_; }
  std::vector<std::string> requests() const { std::lock_guard lock(mutex_); return requests_; }
  int claimed() const { std::lock_guard lock(mutex_); return claimed_; }
  int discarded() const { std::lock_guard lock(mutex_); return discarded_; }
  std::string errors() const { std::lock_guard lock(mutex_); return errors_; }

 private:
  static gboolean on_ioctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
    static_cast<FakeBridge*>(self)->handle(client);
    return TRUE;
  }

  void handle(UMockdevIoctlClient* client) {
    std::lock_guard lock(mutex_);
    const unsigned long request = umockdev_ioctl_client_get_request(client);
    UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
    const std::size_t size = _IOC_SIZE(request);
    GError* error = nullptr;
    UMockdevIoctlData* data = size > 0 ? umockdev_ioctl_data_resolve(arg, 0, size, &error) : nullptr;
    if (error) {
      errors_ += std::string("resolve: ") + error->message + "; ";
      g_error_free(error);
      umockdev_ioctl_client_complete(client, -1, EFAULT);
      return;
    }
    long result = 0;
    int err = 0;
    switch (request) {
      case USBDEVFS_GET_CAPABILITIES:
        // As an xHCI host: with scatter-gather libusb submits a bulk transfer as one URB
        // (without it, as 16 KiB URBs chained by USBDEVFS_URB_BULK_CONTINUATION, which this
        // emulation does not reassemble).
        *reinterpret_cast<std::uint32_t*>(data->data) =
            USBDEVFS_CAP_BULK_SCATTER_GATHER | USBDEVFS_CAP_NO_PACKET_SIZE_LIM |
            USBDEVFS_CAP_BULK_CONTINUATION | USBDEVFS_CAP_ZERO_PACKET |
            USBDEVFS_CAP_REAP_AFTER_DISCONNECT;
        break;
      case USBDEVFS_CLAIMINTERFACE:
        if (unplugged_) result = -1, err = ENODEV;
        else if (claim_busy_) result = -1, err = EBUSY;
        else claimed_ = static_cast<int>(*reinterpret_cast<unsigned*>(data->data));
        break;
      case USBDEVFS_RELEASEINTERFACE:
        claimed_ = -1;
        break;
      case USBDEVFS_GETDRIVER:
      case USBDEVFS_IOCTL:  // connect/disconnect a kernel driver: there is none
        result = -1, err = ENODATA;
        break;
      case USBDEVFS_SUBMITURB:
        if (unplugged_) {
          result = -1, err = ENODEV;
          break;
        }
        submit(data, err);
        if (err != 0) result = -1;
        break;
      case USBDEVFS_DISCARDURB: {
        const gulong target = *reinterpret_cast<gulong*>(arg->data);
        result = -1, err = EINVAL;
        for (auto it = in_flight_.begin(); it != in_flight_.end(); ++it) {
          if (it->urb->client_addr != target) continue;
          it->get()->status = -ENOENT;
          it->get()->actual_length = 0;
          done_.push_back(*it);
          in_flight_.erase(it);
          ++discarded_;
          result = 0, err = 0;
          break;
        }
        break;
      }
      case USBDEVFS_REAPURB:
      case USBDEVFS_REAPURBNDELAY:
        if (done_.empty()) {
          result = -1, err = unplugged_ ? ENODEV : EAGAIN;
        } else {
          Urb u = done_.front();
          done_.pop_front();
          umockdev_ioctl_data_set_ptr(data, 0, u.urb);
          g_object_unref(u.urb);  // the reap's data holds it now
        }
        break;
      default:
        result = -1, err = ENOTTY;
        break;
    }
    if (data) g_object_unref(data);
    umockdev_ioctl_client_complete(client, result, err);
  }

  void submit(UMockdevIoctlData* data, int& err) {
    Urb u;
    u.urb = static_cast<UMockdevIoctlData*>(g_object_ref(data));
    usbdevfs_urb* urb = u.get();
    GError* error = nullptr;
    u.buffer = urb->buffer_length > 0
                   ? umockdev_ioctl_data_resolve(data, offsetof(usbdevfs_urb, buffer),
                                                 static_cast<gsize>(urb->buffer_length), &error)
                   : nullptr;
    if (error) {
      errors_ += std::string("resolve buffer: ") + error->message + "; ";
      g_error_free(error);
      g_object_unref(u.urb);
      err = EFAULT;
      return;
    }
    if (u.buffer) g_object_unref(u.buffer);  // `data` keeps it as a child
    urb->status = 0;
    urb->actual_length = 0;
    if (urb->type == USBDEVFS_URB_TYPE_CONTROL) {
      control(urb);
      done_.push_back(u);
    } else if (urb->type == USBDEVFS_URB_TYPE_BULK && urb->endpoint == 0x01) {
      bulk_out(urb);
      done_.push_back(u);
    } else if (urb->type == USBDEVFS_URB_TYPE_BULK && urb->endpoint == 0x81) {
      in_flight_.push_back(u);
      feed_bulk_in();
    } else {
      g_object_unref(u.urb);
      err = EINVAL;
    }
  }

  static std::uint16_t le16(const std::uint8_t* p) { return static_cast<std::uint16_t>(p[0] | p[1] << 8); }

  void reply(usbdevfs_urb* urb, const std::vector<std::uint8_t>& bytes, std::size_t asked) {
    const std::size_t n = std::min(bytes.size(), asked);
    std::memcpy(static_cast<std::uint8_t*>(urb->buffer) + 8, bytes.data(), n);
    urb->actual_length = static_cast<int>(n);
  }

  void control(usbdevfs_urb* urb) {
    const auto* setup = static_cast<const std::uint8_t*>(urb->buffer);
    const std::uint8_t type = setup[0], request = setup[1];
    const std::uint16_t value = le16(setup + 2), length = le16(setup + 6);
    const std::uint8_t* payload = setup + 8;
    if (type == 0x80 && request == 6 && (value >> 8) == 3) {  // GET_DESCRIPTOR string
      const unsigned index = value & 0xFF;
      if (index == 0) return reply(urb, {4, 3, 0x09, 0x04}, length);
      const std::string text = index == 1 ? "idm" : index == 2 ? "bridge" : index == 3 ? serial_ : "";
      if (text.empty()) return stall(urb);
      std::vector<std::uint8_t> d = {static_cast<std::uint8_t>(2 + 2 * text.size()), 3};
      for (char c : text) d.insert(d.end(), {static_cast<std::uint8_t>(c), 0});
      return reply(urb, d, length);
    }
    if ((type != kRequestTypeOut && type != kRequestTypeIn) || le16(setup + 4) != 0)
      return stall(urb);
    std::vector<std::uint8_t> out;
    switch (static_cast<Request>(request)) {
      case Request::GetInfo:
        requests_.push_back("GET_INFO");
        encode_info(info_, out);
        return reply(urb, out, length);
      case Request::GetStatus:
        requests_.push_back("GET_STATUS");
        status_.device_time_ticks = ticks_now();
        encode_status(status_, out);
        return reply(urb, out, length);
      case Request::Configure: {
        requests_.push_back("CONFIGURE");
        if (length != kConfigureBytes ||
            !decode_config(std::span<const std::uint8_t>(payload, length), config_).ok())
          return stall(urb);
        status_ = {};
        status_.state = BridgeState::Configured;
        codes_.clear();
        out_sequence_.reset(0);
        in_sequence_ = 0;
        urb->actual_length = length;
        return;
      }
      case Request::Start:
        requests_.push_back("START");
        if (status_.state != BridgeState::Configured) return stall(urb);
        play();
        return;
      case Request::Stop:
        requests_.push_back("STOP");
        status_.state = status_.state == BridgeState::Idle ? BridgeState::Idle : BridgeState::Finished;
        return;
      case Request::Latch:
        requests_.push_back("LATCH");
        if (!has_latch_) return stall(urb);
        encode_latch({ticks_now(),
                      encode_position_word(position_, WordWidth::Bits32)},
                     out);
        return reply(urb, out, length);
    }
    return stall(urb);
  }

  // The bridge's free-running clock (device_time_ticks): ticks since it was switched on.
  std::uint64_t ticks_now() const {
    const std::chrono::duration<double> up = std::chrono::steady_clock::now() - power_up_;
    return static_cast<std::uint64_t>(up.count() * static_cast<double>(info_.tick_hz));
  }

  static void stall(usbdevfs_urb* urb) {
    urb->status = -EPIPE;
    urb->actual_length = 0;
  }

  void bulk_out(usbdevfs_urb* urb) {
    const std::span<const std::uint8_t> bytes(static_cast<const std::uint8_t*>(urb->buffer),
                                              static_cast<std::size_t>(urb->buffer_length));
    WaveformBlock block;
    std::size_t consumed = 0;
    const CodecStatus s = decode_waveform_block(bytes, block, consumed);
    if (!s.ok() || consumed != bytes.size()) {
      errors_ += "bulk OUT: " + s.message + "; ";
      status_.fault_flags |= fault_flag::kCrcError;
    } else if (!out_sequence_.check(block.sequence).ok()) {
      status_.fault_flags |= fault_flag::kSequenceError;
    } else {
      codes_.insert(codes_.end(), block.dac_codes.begin(), block.dac_codes.end());
      status_.next_waveform_sequence = out_sequence_.expected();
    }
    urb->actual_length = urb->buffer_length;
  }

  // START: the burst plays at once; the position records (one per position tick during the burst
  // and its tail, count = the DAC code being played) wait for bulk IN in packets of 100.
  void play() {
    const std::uint64_t dac = config_.dac_sample_rate_hz, pos = config_.position_sample_rate_hz;
    const std::uint64_t n = config_.burst_samples * pos / dac + config_.tail_samples;
    std::vector<PositionRecord> records;
    for (std::uint64_t k = 0; k < n; ++k) {
      const std::uint64_t i = k * dac / pos;
      const std::int64_t count = i < codes_.size() ? codes_[i] : 0;
      records.push_back({1000 + k * info_.tick_hz / pos, encode_position_word(count, WordWidth::Bits32)});
    }
    for (std::size_t first = 0; first < records.size() || first == 0; first += 100) {
      PositionPacket p;
      p.sequence = in_sequence_++;
      const std::size_t end = std::min(records.size(), first + 100);
      p.samples.assign(records.begin() + static_cast<std::ptrdiff_t>(first),
                       records.begin() + static_cast<std::ptrdiff_t>(end));
      p.flags = static_cast<std::uint8_t>((first == 0 ? packet_flag::kFirst : 0) |
                                          (end == records.size() ? packet_flag::kLast : 0));
      std::vector<std::uint8_t> bytes;
      encode_position_packet(p, bytes);
      packets_.push_back(std::move(bytes));
      if (end == records.size()) break;
    }
    status_.state = BridgeState::Finished;
    status_.dac_samples_played = config_.burst_samples;
    status_.positions_latched = static_cast<std::uint32_t>(n);
    feed_bulk_in();
  }

  // Completes waiting bulk IN URBs with as many whole packets as fit (several per transfer).
  void feed_bulk_in() {
    while (!mute_in_ && !in_flight_.empty() && !packets_.empty()) {
      Urb u = in_flight_.front();
      in_flight_.pop_front();
      usbdevfs_urb* urb = u.get();
      std::size_t used = 0;
      while (!packets_.empty() &&
             used + packets_.front().size() <= static_cast<std::size_t>(urb->buffer_length)) {
        std::memcpy(static_cast<std::uint8_t*>(urb->buffer) + used, packets_.front().data(),
                    packets_.front().size());
        used += packets_.front().size();
        packets_.pop_front();
      }
      urb->actual_length = static_cast<int>(used);
      done_.push_back(u);
    }
  }

  mutable std::mutex mutex_;
  std::string serial_;
  int devnum_;
  UMockdevIoctlBase* handler_ = nullptr;
  BridgeInfo info_;
  BridgeStatus status_;
  BridgeConfig config_;
  SequenceTracker out_sequence_;
  std::uint32_t in_sequence_ = 0;
  std::vector<std::int32_t> codes_;
  std::deque<std::vector<std::uint8_t>> packets_;
  std::deque<Urb> in_flight_;
  std::deque<Urb> done_;
  std::vector<std::string> requests_;
  std::string errors_;
  std::int64_t position_ = 0;
  int claimed_ = -1;
  int discarded_ = 0;
  bool unplugged_ = false;
  // Switched on an hour before the test: a power cycle restarts the clock visibly.
  std::chrono::steady_clock::time_point power_up_ =
      std::chrono::steady_clock::now() - std::chrono::hours(1);
  bool claim_busy_ = false;
  bool mute_in_ = false;
  bool has_latch_ = true;
};

// A testbed with the given bridges (each on its own /dev/bus/usb/001/NNN).
class Testbed {
 public:
  Testbed() : testbed_(umockdev_testbed_new()) {}
  ~Testbed() {
    bridges_.clear();
    g_object_unref(testbed_);
  }
  FakeBridge& add(const std::string& serial) {
    bridges_.push_back(std::make_unique<FakeBridge>(serial, static_cast<int>(bridges_.size()) + 2));
    FakeBridge& b = *bridges_.back();
    GError* error = nullptr;
    const bool added = umockdev_testbed_add_from_string(testbed_, b.record().c_str(), &error) &&
                       umockdev_testbed_attach_ioctl(testbed_, b.devnode().c_str(), b.handler(), &error);
    EXPECT_TRUE(added) << (error ? error->message : "");
    if (error) g_error_free(error);
    return b;
  }

 private:
  UMockdevTestbed* testbed_;
  std::vector<std::unique_ptr<FakeBridge>> bridges_;
};

UsbTransportConfig bridge_config(const std::string& serial) {
  UsbTransportConfig c;
  c.serial = serial;
  c.timeout_s = 0.2;
  return c;
}

}  // namespace

TEST(UsbUmockdev, OpensTheBridgeByIdAndSerialAndClaimsIt) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& a = bed.add("A17");
  FakeBridge& b = bed.add("B12");
  UsbTransport t(bridge_config("B12"));  // the second of two bridges with the same ids
  const DriverStatus s = t.open();
  ASSERT_TRUE(s.ok()) << s.message << " / " << b.errors();
  EXPECT_TRUE(t.is_open());
  EXPECT_EQ(b.claimed(), 0);
  EXPECT_EQ(a.claimed(), -1);
  EXPECT_EQ(b.requests(), std::vector<std::string>{"GET_INFO"});
  EXPECT_TRUE(a.requests().empty());
  EXPECT_EQ(t.info().tick_hz, 1000000u);
  EXPECT_EQ(t.info().buffer_capacity_samples, 65536u);
  t.close();
  EXPECT_EQ(b.claimed(), -1);  // released

  UsbTransport first(bridge_config("A17"));
  ASSERT_TRUE(first.open().ok());
  EXPECT_EQ(a.claimed(), 0);
}

TEST(UsbUmockdev, AWrongSerialIsNoDeviceNamingWhatWasFound) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  bed.add("A17");
  bed.add("B12");
  UsbTransport t(bridge_config("C99"));
  const DriverStatus s = t.open();
  EXPECT_EQ(s.error, DriverError::NoDevice) << s.message;
  // libusb lists the newest device first; the message names both
  EXPECT_TRUE(s.message.find("open: no USB device 1209:4944 serial C99 (found serials: B12, A17)") !=
                  std::string::npos ||
              s.message.find("open: no USB device 1209:4944 serial C99 (found serials: A17, B12)") !=
                  std::string::npos)
      << s.message;
  EXPECT_FALSE(t.is_open());

  UsbTransportConfig other = bridge_config("");
  other.product_id = 0x4945;
  UsbTransport none(other);
  const DriverStatus n = none.open();
  EXPECT_EQ(n.error, DriverError::NoDevice) << n.message;
  EXPECT_NE(n.message.find("no USB device 1209:4945 (2 USB devices present, none with that id)"),
            std::string::npos)
      << n.message;
}

TEST(UsbUmockdev, ABusyInterfaceIsADeviceErrorAndNothingStaysOpen) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& b = bed.add("B12");
  b.set_claim_busy(true);
  UsbTransport t(bridge_config(""));
  const DriverStatus s = t.open();
  EXPECT_EQ(s.error, DriverError::DeviceError) << s.message;
  EXPECT_NE(s.message.find("open: claiming interface 0: the interface of 1209:4944 is claimed by "
                           "another program or driver (LIBUSB_ERROR_BUSY)"),
            std::string::npos)
      << s.message;
  EXPECT_FALSE(t.is_open());
  b.set_claim_busy(false);
  EXPECT_TRUE(t.open().ok());
}

TEST(UsbUmockdev, ABurstGoesOutAndItsPositionsComeBackThroughLibusb) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& b = bed.add("B12");
  UsbTransport t(bridge_config("B12"));
  ASSERT_TRUE(t.open().ok());
  std::vector<std::int32_t> codes(20000);  // three waveform blocks: 8192 + 8192 + 3616
  for (std::size_t i = 0; i < codes.size(); ++i) codes[i] = static_cast<std::int32_t>(i % 30000) - 15000;
  BridgeConfig bc;
  bc.dac_sample_rate_hz = 100000;
  bc.burst_samples = static_cast<std::uint32_t>(codes.size());
  bc.position_sample_rate_hz = 50000;
  bc.tail_samples = 10;
  ASSERT_TRUE(t.configure(bc).ok());
  ASSERT_TRUE(t.send_waveform(codes, SampleFormat::DacInt16).ok());
  EXPECT_EQ(b.codes(), codes) << b.errors();
  EXPECT_EQ(b.config().burst_samples, 20000u);
  ASSERT_TRUE(t.start().ok());
  BridgeStatus status;
  ASSERT_TRUE(t.get_status(status).ok());
  EXPECT_EQ(status.state, BridgeState::Finished);
  EXPECT_EQ(status.fault_flags, 0);
  EXPECT_EQ(status.next_waveform_sequence, 3u);

  std::vector<PositionRecord> records;
  PositionTransfer info;
  int transfers = 0;
  while (!info.last && transfers < 100) {
    const DriverStatus s = t.receive_positions(records, info);
    ASSERT_TRUE(s.ok()) << s.message;
    ++transfers;
  }
  EXPECT_TRUE(info.last);
  EXPECT_FALSE(info.lost);
  ASSERT_EQ(records.size(), 10010u);  // 20000 samples at 1e5 Hz latched at 5e4 Hz, + 10
  EXPECT_EQ(transfers, 3);  // 101 packets of up to 1620 bytes, 40 fit a 65616-byte transfer
  for (std::size_t k = 0; k < 10000; k += 997) {
    EXPECT_EQ(records[k].timestamp_ticks, 1000 + 20 * k);
    EXPECT_EQ(records[k].position_word, encode_position_word(codes[2 * k], WordWidth::Bits32)) << k;
  }
  const std::vector<std::string> expected = {"GET_INFO", "CONFIGURE", "START", "GET_STATUS"};
  EXPECT_EQ(b.requests(), expected);
}

TEST(UsbUmockdev, ASilentBridgeTimesOutAndAStallIsNamed) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& b = bed.add("B12");
  UsbTransport t(bridge_config("B12"));
  ASSERT_TRUE(t.open().ok());
  b.set_mute_bulk_in(true);
  std::vector<PositionRecord> records;
  PositionTransfer info;
  DriverStatus s = t.receive_positions(records, info);
  EXPECT_EQ(s.error, DriverError::Timeout) << s.message;
  EXPECT_NE(s.message.find("receive_positions: bulk IN: the USB device 1209:4944 serial B12 did "
                           "not answer in time (LIBUSB_ERROR_TIMEOUT)"),
            std::string::npos)
      << s.message;
  EXPECT_EQ(b.discarded(), 1);  // libusb cancelled the URB
  EXPECT_TRUE(t.is_open());     // a timeout keeps the handle

  s = t.start();  // not configured: the bridge stalls START
  EXPECT_EQ(s.error, DriverError::DeviceError) << s.message;
  EXPECT_NE(s.message.find("start: the bridge 1209:4944 serial B12 stalled the request"),
            std::string::npos)
      << s.message;
}

TEST(UsbUmockdev, UnpluggingIsDisconnectedAndClosesTheHandle) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& b = bed.add("B12");
  UsbTransport t(bridge_config("B12"));
  ASSERT_TRUE(t.open().ok());
  b.unplug();
  BridgeStatus status;
  const DriverStatus s = t.get_status(status);
  EXPECT_EQ(s.error, DriverError::Disconnected) << s.message;
  EXPECT_NE(s.message.find("get_status: the USB device 1209:4944 serial B12 is gone (unplugged?) "
                           "(LIBUSB_ERROR_NO_DEVICE)"),
            std::string::npos)
      << s.message;
  EXPECT_FALSE(t.is_open());
  EXPECT_EQ(t.start().error, DriverError::InvalidState);
}

TEST(UsbUmockdev, TheBackendPlaysABurstAndLatches) {
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& b = bed.add("B12");
  Device d = make_backend(
      "usb",
      YAML::Load("daq: {usb: {serial: B12, position_rate_hz: 5e4, tail_s: 2e-4, timeout_s: 0.2}}"),
      "u.yaml");
  ASSERT_TRUE(d.configure().ok());
  ASSERT_TRUE(d.activate().ok());
  b.set_position(-1234);
  std::uint64_t word = 0;
  DriverStatus s = d.interferometer->latch(word);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(word, encode_position_word(-1234, WordWidth::Bits32));

  // a burst 0 -> 1 um -> 0 in 1001 samples at 100 kHz
  std::vector<double> xi(1001);
  for (std::size_t k = 0; k < xi.size(); ++k) xi[k] = 1e-6 * (1.0 - std::abs(k / 500.0 - 1.0));
  ASSERT_TRUE(d.output->write_burst(xi.data(), xi.size(), 1e5).ok());
  ASSERT_TRUE(d.output->start().ok());
  bool done = false;
  ASSERT_TRUE(d.output->is_done(done).ok());
  EXPECT_TRUE(done);
  std::vector<TimedWord> stream(2000);
  std::size_t n = 0;
  s = d.interferometer->read_stream(stream.data(), stream.size(), n);
  ASSERT_TRUE(s.ok()) << s.message;
  ASSERT_EQ(n, 510u);  // 1001 samples at 1e5 latched at 5e4 (500) + 2e-4 s tail (10)
  EXPECT_DOUBLE_EQ(stream[0].t_s, 0.0);
  EXPECT_DOUBLE_EQ(stream[250].t_s, 250 * 20e-6);
  const OutputCapabilities& caps = d.output->capabilities();
  EXPECT_EQ(stream[250].word, encode_position_word(dac_code(xi[500], caps), WordWidth::Bits32));
  EXPECT_EQ(b.codes().size(), 1001u);

  b.set_has_latch(false);  // firmware without LATCH stalls it
  s = d.interferometer->latch(word);
  EXPECT_EQ(s.error, DriverError::Unsupported) << s.message;
  EXPECT_NE(s.message.find("stalled LATCH"), std::string::npos) << s.message;
  EXPECT_TRUE(d.shutdown().ok());
}

// The device link over the USB backend: an unplugged bridge is lost at once (the output stopped,
// the health naming why), taken back by itself, and its position continues from the bridge's own
// count when the bridge kept it (a pulled cable) and from the last good reading when it did not
// (a power cycle: the bridge's clock and count started over).
TEST(UsbUmockdev, TheLinkLosesAnUnpluggedBridgeAndTakesItBackKeepingOrNotItsCount) {
  using idm::model::AxisEvent;
  IDM_UNDER_UMOCKDEV();
  Testbed bed;
  FakeBridge& b = bed.add("B12");
  b.set_position(1000);
  std::vector<Device> channels;
  channels.push_back(make_backend(
      "usb", YAML::Load("daq: {usb: {serial: B12, position_rate_hz: 5e4, timeout_s: 0.2}}"),
      "u.yaml"));
  idm::drivers::LinkConfig config;
  config.reconnect_min_s = 0.05;
  config.reconnect_max_s = 0.2;
  idm::drivers::DeviceLink link("bridge", std::move(channels), config);
  ASSERT_TRUE(link.open().ok());

  double now_s = 0;
  std::vector<AxisEvent> events;
  const auto run = [&](double seconds) {
    AxisEvent e;
    for (const double end = now_s + seconds; now_s < end; now_s += 1e-3) {
      link.service(now_s);
      while (link.port(0).events.pop(e)) events.push_back(e);
    }
  };
  const auto count_of = [&](AxisEvent::Kind kind) {
    return std::count_if(events.begin(), events.end(), [&](const AxisEvent& e) { return e.kind == kind; });
  };
  const auto last_valid_m = [&] {
    for (auto it = events.rbegin(); it != events.rend(); ++it)
      if (it->valid()) return it->position_m;
    return std::nan("");
  };

  run(0.02);
  ASSERT_EQ(link.health().state, idm::drivers::LinkState::Up) << link.health().message;
  const double count_m = last_valid_m() / 1000;
  ASSERT_GT(count_m, 0);

  b.unplug();
  events.clear();
  run(0.02);
  EXPECT_EQ(count_of(AxisEvent::Kind::DeviceLost), 1);
  EXPECT_EQ(link.health().state, idm::drivers::LinkState::Lost);
  EXPECT_NE(std::string(link.health().message).find("is gone (unplugged?)"), std::string::npos)
      << link.health().message;
  EXPECT_TRUE(std::isnan(last_valid_m())) << "no valid reading while lost";

  b.set_position(1500);  // the slider moved while the cable was out; the bridge counted it
  b.replug();
  events.clear();
  run(1.0);
  ASSERT_EQ(link.health().state, idm::drivers::LinkState::Up) << link.health().message;
  ASSERT_EQ(count_of(AxisEvent::Kind::DeviceBack), 1);
  EXPECT_TRUE(std::find_if(events.begin(), events.end(), [](const AxisEvent& e) {
                return e.kind == AxisEvent::Kind::DeviceBack;
              })->count_kept);
  EXPECT_NEAR(last_valid_m() / count_m, 1500, 1e-6);
  EXPECT_EQ(link.health().losses, 1u);
  EXPECT_EQ(link.health().reconnects, 1u);

  b.unplug();
  run(0.02);
  b.power_cycle();  // back with its clock and count at zero
  b.set_position(200);
  events.clear();
  run(1.0);
  ASSERT_EQ(link.health().state, idm::drivers::LinkState::Up) << link.health().message;
  const auto back = std::find_if(events.begin(), events.end(), [](const AxisEvent& e) {
    return e.kind == AxisEvent::Kind::DeviceBack;
  });
  ASSERT_NE(back, events.end());
  EXPECT_FALSE(back->count_kept);
  EXPECT_NEAR(last_valid_m() / count_m, 1500, 1e-6) << "continues from the last good reading";
  b.set_position(260);
  run(0.02);
  EXPECT_NEAR(last_valid_m() / count_m, 1560, 1e-6) << "and follows the bridge's count from there";
  link.close();
}
