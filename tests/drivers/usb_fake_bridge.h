// The USB bridge emulated behind umockdev (test_usb_umockdev.cpp): FakeBridge answers the
// usbdevfs ioctls on its /dev/bus/usb node (descriptors, control requests, bulk transfers) as
// drivers/usb/README.md specifies; Testbed puts bridges on umockdev's testbed.
#pragma once

#include <gtest/gtest.h>
#include <linux/usbdevice_fs.h>
#include <sys/ioctl.h>
#include <umockdev.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "drivers/position_word.h"
#include "drivers/usb/protocol.h"
#include "drivers/usb/transport.h"

namespace idm::drivers::usb::fake {

// ---- the emulated bridge ----

inline std::string hex(const std::vector<std::uint8_t>& bytes) {
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
inline std::vector<std::uint8_t> descriptors() {
  return {0x12, 0x01, 0x00, 0x02, 0x00, 0x00, 0x00, 0x40, 0x09,
          0x12, 0x44, 0x49, 0x00, 0x01, 0x01, 0x02, 0x03, 0x01,  // device
          0x09, 0x02, 0x20, 0x00, 0x01, 0x01, 0x00, 0x80, 0x32,  // configuration
          0x09, 0x04, 0x00, 0x00, 0x02, 0xFF, 0x00, 0x00, 0x00,  // interface 0
          0x07, 0x05, 0x01, 0x02, 0x00, 0x02, 0x00,              // bulk OUT 0x01
          0x07, 0x05, 0x81, 0x02, 0x00, 0x02, 0x00};             // bulk IN 0x81
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
  void unplug() {
    std::lock_guard lock(mutex_);
    unplugged_ = true;
  }
  void replug() {
    std::lock_guard lock(mutex_);
    unplugged_ = false;
  }
  // Switched off and on: back at once with its clock and its count started over, unconfigured.
  void power_cycle() {
    std::lock_guard lock(mutex_);
    unplugged_ = false;
    power_up_ = std::chrono::steady_clock::now();
    position_ = 0;
    status_ = {};
  }
  void set_claim_busy(bool busy) {
    std::lock_guard lock(mutex_);
    claim_busy_ = busy;
  }
  void set_mute_bulk_in(bool mute) {
    std::lock_guard lock(mutex_);
    mute_in_ = mute;
  }
  void set_has_latch(bool has) {
    std::lock_guard lock(mutex_);
    has_latch_ = has;
  }
  void set_position(std::int64_t count) {
    std::lock_guard lock(mutex_);
    position_ = count;
  }

  // What the bridge saw.
  std::vector<std::int32_t> codes() const {
    std::lock_guard lock(mutex_);
    return codes_;
  }
  BridgeConfig config() const {
    std::lock_guard lock(mutex_);
    return config_;
  }
  std::vector<std::string> requests() const {
    std::lock_guard lock(mutex_);
    return requests_;
  }
  int claimed() const {
    std::lock_guard lock(mutex_);
    return claimed_;
  }
  int discarded() const {
    std::lock_guard lock(mutex_);
    return discarded_;
  }
  std::string errors() const {
    std::lock_guard lock(mutex_);
    return errors_;
  }

 private:
  // The reply goes out after the mutex is released: once the client has it, the test may go
  // on to destroy this bridge, and the worker thread must not touch it any more.
  static gboolean on_ioctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
    long result = 0;
    int err = 0;
    static_cast<FakeBridge*>(self)->handle(client, result, err);
    umockdev_ioctl_client_complete(client, result, err);
    return TRUE;
  }

  void handle(UMockdevIoctlClient* client, long& result, int& err) {
    std::lock_guard lock(mutex_);
    const unsigned long request = umockdev_ioctl_client_get_request(client);
    UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
    const std::size_t size = _IOC_SIZE(request);
    GError* error = nullptr;
    UMockdevIoctlData* data =
        size > 0 ? umockdev_ioctl_data_resolve(arg, 0, size, &error) : nullptr;
    if (error) {
      errors_ += std::string("resolve: ") + error->message + "; ";
      g_error_free(error);
      result = -1, err = EFAULT;
      return;
    }
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
        if (unplugged_)
          result = -1, err = ENODEV;
        else if (claim_busy_)
          result = -1, err = EBUSY;
        else
          claimed_ = static_cast<int>(*reinterpret_cast<unsigned*>(data->data));
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

  static std::uint16_t le16(const std::uint8_t* p) {
    return static_cast<std::uint16_t>(p[0] | p[1] << 8);
  }

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
      const std::string text = index == 1   ? "idm"
                               : index == 2 ? "bridge"
                               : index == 3 ? serial_
                                            : "";
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
        status_.state =
            status_.state == BridgeState::Idle ? BridgeState::Idle : BridgeState::Finished;
        return;
      case Request::Latch:
        requests_.push_back("LATCH");
        if (!has_latch_) return stall(urb);
        encode_latch({ticks_now(), encode_position_word(position_, WordWidth::Bits32)}, out);
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
      records.push_back(
          {1000 + k * info_.tick_hz / pos, encode_position_word(count, WordWidth::Bits32)});
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
  // The testbed (and its worker thread, which calls into the bridges) goes first.
  ~Testbed() {
    g_object_unref(testbed_);
    bridges_.clear();
  }
  FakeBridge& add(const std::string& serial) {
    bridges_.push_back(std::make_unique<FakeBridge>(serial, static_cast<int>(bridges_.size()) + 2));
    FakeBridge& b = *bridges_.back();
    GError* error = nullptr;
    const bool added =
        umockdev_testbed_add_from_string(testbed_, b.record().c_str(), &error) &&
        umockdev_testbed_attach_ioctl(testbed_, b.devnode().c_str(), b.handler(), &error);
    EXPECT_TRUE(added) << (error ? error->message : "");
    if (error) g_error_free(error);
    return b;
  }

 private:
  UMockdevTestbed* testbed_;
  std::vector<std::unique_ptr<FakeBridge>> bridges_;
};

}  // namespace idm::drivers::usb::fake
