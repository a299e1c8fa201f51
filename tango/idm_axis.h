// The Tango device class IdmAxis: one device per idmd axis, a client of idmd's socket (README.md
// here). Attributes Position (r/w, m, min/max from the soft limits), Target, Referenced, Window,
// Hold, Velocity, Offset, StatusBits; State ON/MOVING/FAULT/ALARM/DISABLE; commands Stop,
// Reference, Step, JogPositive, JogNegative, SetPosition; change events on Position and State,
// pushed while the axis moves.
#pragma once

#include <tango.h>

#include <atomic>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "client/connection.h"
#include "client/replies.h"
#include "tango/axis_state.h"

namespace idm::tango {

class IdmAxis : public TANGO_BASE_CLASS {
 public:
  IdmAxis(Tango::DeviceClass* cl, const char* name);
  IdmAxis(const IdmAxis&) = delete;
  IdmAxis& operator=(const IdmAxis&) = delete;
  ~IdmAxis() override;

  void init_device() override;
  void delete_device() override;
  Tango::DevState dev_state() override;
  Tango::ConstDevString dev_status() override;
  void read_attr_hardware(std::vector<long>& attrs) override;

  void read_Position(Tango::Attribute& att);
  void write_Position(Tango::WAttribute& att);
  void read_Target(Tango::Attribute& att);
  void read_Referenced(Tango::Attribute& att);
  void read_Window(Tango::Attribute& att);
  void write_Window(Tango::WAttribute& att);
  void read_Hold(Tango::Attribute& att);
  void write_Hold(Tango::WAttribute& att);
  void read_Velocity(Tango::Attribute& att);
  void write_Velocity(Tango::WAttribute& att);
  void read_Offset(Tango::Attribute& att);
  void write_Offset(Tango::WAttribute& att);
  void read_StatusBits(Tango::Attribute& att);

  void stop();
  void reference();
  void step(Tango::DevLong cycles);
  // JOG POSitive (positive) or JOG NEGative: toward that soft limit at the speed limit.
  void jog(bool positive);
  // POSition:SET: the current position becomes `position_m` (the user offset changes).
  void set_position(Tango::DevDouble position_m);

 private:
  // With a database: the properties IdmdSocket or IdmdAddress (idmd's address, both set is an
  // error) and Axis, over the environment and the name; a bad one (or none readable) sets
  // config_error_. Returns whether a property gave the address.
  bool read_properties();
  // One protocol line to this device's axis ("AXIS<n>:" put in front), under the connection's
  // lock; the daemon's errors and a lost connection as Tango exceptions.
  std::string query(const std::string& header, const char* origin);
  void command(const std::string& line, const char* origin);
  // A setting of the axis as a double attribute: read `header?`, write `header <value>`.
  void read_setting(Tango::Attribute& att, const std::string& header, Tango::DevDouble& value,
                    const char* origin);
  void write_setting(Tango::WAttribute& att, const std::string& header, const char* origin);
  // STATus? now; on failure the reason is kept and the state is FAULT.
  void refresh();
  // From the last refresh: Tango's state and status, and the Position's min/max from the soft
  // limits. Called with the device's monitor held.
  void apply_status();
  // Pushes State when it changed, and Position while moving and once when the motion ended.
  // Called with the device's monitor held.
  void publish();
  // refresh(), apply_status() and publish(): after a command.
  void resync();
  void monitor_loop();

  client::Address address_;
  int axis_ = 0;
  std::string config_error_;  // a device that cannot work (bad name or property): why

  std::mutex mutex_;  // the connection and the fields below
  std::unique_ptr<client::Client> client_;
  std::optional<client::AxisStatus> status_;
  std::string status_error_;

  // Tango's buffers for the attributes (set_value keeps a pointer until the reply is sent).
  Tango::DevDouble position_ = 0, target_ = 0, window_ = 0, hold_ = 0, velocity_ = 0, offset_ = 0;
  Tango::DevDouble event_position_ = 0;
  Tango::DevBoolean referenced_ = false;
  Tango::DevLong status_bits_ = 0;
  std::string status_text_;
  double limit_lo_ = 0, limit_hi_ = 0;
  bool limits_set_ = false;
  AxisState last_state_ = AxisState::Fault;
  bool last_state_known_ = false;

  std::atomic<bool> stopping_{false};
  std::thread monitor_;
};

class IdmAxisClass : public Tango::DeviceClass {
 public:
  static IdmAxisClass* init(const char* name);
  static IdmAxisClass* instance();

 protected:
  explicit IdmAxisClass(std::string& name);
  void command_factory() override;
  void attribute_factory(std::vector<Tango::Attr*>& attrs) override;
  void device_factory(const Tango::DevVarStringArray* devlist) override;

 private:
  static IdmAxisClass* instance_;
};

}  // namespace idm::tango
