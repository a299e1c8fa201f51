// The USB transport and backend through real libusb against an emulated bridge: umockdev's testbed
// provides the sysfs entries and /dev/bus/usb nodes libusb enumerates, and its ioctl emulation
// hands every usbdevfs ioctl on the node (SUBMITURB, REAPURB, DISCARDURB, CLAIMINTERFACE, ...) to
// FakeBridge (usb_fake_bridge.h), which answers the control requests and bulk transfers as
// drivers/usb/README.md specifies. libusb and UsbTransport run unmodified: enumeration by
// vid:pid:serial, claiming, string descriptors, control transfers, bulk OUT and IN, timeouts
// (DISCARDURB), stalls and unplugging (ENODEV) all go through the real code paths.
//
// umockdev needs libumockdev-preload in LD_PRELOAD. Each test re-runs itself (this binary, with
// --gtest_filter=the test) with the preload; the re-run's exit status is the test's result. The
// test is skipped only when the preload cannot be loaded (umockdev not installed).
#include <dlfcn.h>
#include <gtest/gtest.h>
#include <link.h>
#include <linux/usbdevice_fs.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <umockdev.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

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

#include "drivers/backends.h"
#include "drivers/link.h"
#include "drivers/position_word.h"
#include "drivers/usb/transport.h"
#include "drivers/usb/usb_backend.h"
#include "tests/drivers/usb_fake_bridge.h"

using namespace idm::drivers;
using namespace idm::drivers::usb;
using idm::drivers::usb::fake::FakeBridge;
using idm::drivers::usb::fake::Testbed;

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

bool preload_active() {
  return dlopen(kPreload, RTLD_LAZY | RTLD_NOLOAD) != nullptr;
}

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

#define IDM_UNDER_UMOCKDEV()                                                                \
  switch (run_under_umockdev()) {                                                           \
    case Run::Here:                                                                         \
      break;                                                                                \
    case Run::NoUmockdev:                                                                   \
      /* ./idm test installs umockdev, so a preload that fails is a broken set-up, not a */ \
      /* reason to pass: the test fails and says what to install. */                        \
      FAIL() << "umockdev is not usable here: " << kPreload                                 \
             << " cannot be preloaded (install the Debian package umockdev)";               \
    case Run::Done:                                                                         \
      return;                                                                               \
  }

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
  EXPECT_TRUE(
      s.message.find("open: no USB device 1209:4944 serial C99 (found serials: B12, A17)") !=
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
  for (std::size_t i = 0; i < codes.size(); ++i)
    codes[i] = static_cast<std::int32_t>(i % 30000) - 15000;
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
    return std::count_if(events.begin(), events.end(),
                         [&](const AxisEvent& e) { return e.kind == kind; });
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
