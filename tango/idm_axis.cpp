#include "tango/idm_axis.h"

#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>

namespace idm::tango {

namespace {

constexpr double kTimeoutS = 5;
constexpr int kMaxAxis = 1000;
constexpr auto kMonitorPeriod = std::chrono::milliseconds(100);

std::string number_text(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.12g", v);
  return buf;
}

Tango::DevState tango_state(AxisState s) {
  switch (s) {
    case AxisState::On:
      return Tango::ON;
    case AxisState::Moving:
      return Tango::MOVING;
    case AxisState::Fault:
      return Tango::FAULT;
    case AxisState::Alarm:
      return Tango::ALARM;
    case AxisState::Disable:
      return Tango::DISABLE;
  }
  return Tango::UNKNOWN;
}

// An axis number 1..kMaxAxis written in decimal digits alone; 0 when `text` is none.
int axis_number(const std::string& text) {
  if (text.empty() || text.size() > 4 || text.find_first_not_of("0123456789") != std::string::npos)
    return 0;
  const int n = std::stoi(text);
  return n <= kMaxAxis ? n : 0;
}

// The axis a device name stands for: idm/axis/<n> is axis n; 0 when the last member is no number.
int axis_from_name(const std::string& name) {
  const std::size_t slash = name.rfind('/');
  return axis_number(slash == std::string::npos ? name : name.substr(slash + 1));
}

// A property's text (its first value); false when the database holds none.
bool property_text(Tango::DbDatum& datum, std::string& text) {
  if (datum.is_empty()) return false;
  datum >> text;
  return true;
}

}  // namespace

IdmAxis::IdmAxis(Tango::DeviceClass* cl, const char* name) : TANGO_BASE_CLASS(cl, name) {
  init_device();
}

IdmAxis::~IdmAxis() {
  delete_device();
}

void IdmAxis::init_device() {
  set_state(Tango::INIT);
  config_error_.clear();
  address_ = client::Address{};
  axis_ = axis_from_name(get_name());
  // With a database, the device's properties override the environment and the name.
  const bool address_from_property = Tango::Util::_UseDb && read_properties();
  if (!address_from_property) {
    try {
      address_ = client::address_from_environment();
    } catch (const client::AddressError& e) {
      if (config_error_.empty()) config_error_ = e.what();
    }
  }
  if (config_error_.empty() && axis_ == 0)
    config_error_ = "device " + get_name() +
                    ": the name does not end in an axis number (idm/axis/<n>) and no Axis property "
                    "says which axis it is";
  set_change_event("Position", true, false);
  set_change_event("State", true, false);
  refresh();
  apply_status();
  stopping_ = false;
  monitor_ = std::thread([this] { monitor_loop(); });
}

bool IdmAxis::read_properties() {
  Tango::DbData props;
  props.push_back(Tango::DbDatum("IdmdAddress"));
  props.push_back(Tango::DbDatum("IdmdSocket"));
  props.push_back(Tango::DbDatum("Axis"));
  try {
    get_db_device()->get_property(props);
  } catch (const Tango::DevFailed& e) {
    config_error_ = "cannot read the device's properties: " + std::string(e.errors[0].desc.in());
    return false;
  }
  std::string address_text, socket_path, axis_text;
  const bool has_address = property_text(props[0], address_text);
  const bool has_socket = property_text(props[1], socket_path);
  if (property_text(props[2], axis_text)) {
    axis_ = axis_number(axis_text);
    if (axis_ == 0)
      config_error_ = "property Axis: '" + axis_text.substr(0, 40) +
                      "' is not an axis number (1.." + std::to_string(kMaxAxis) + ")";
  }
  std::string address_error;
  if (has_socket && has_address) {
    address_error = "properties IdmdSocket and IdmdAddress are both set: set one";
  } else if (has_socket) {
    address_.unix_path = socket_path;
    if (socket_path.empty()) address_error = "property IdmdSocket: an empty path";
  } else if (has_address) {
    try {
      address_ = client::parse_host_port(address_text);
    } catch (const client::AddressError& e) {
      address_error = std::string("property IdmdAddress: ") + e.what();
    }
  }
  if (config_error_.empty()) config_error_ = address_error;
  return has_socket || has_address;
}

void IdmAxis::delete_device() {
  stopping_ = true;
  if (monitor_.joinable()) monitor_.join();
  std::lock_guard<std::mutex> lock(mutex_);
  client_.reset();
}

std::string IdmAxis::query(const std::string& header, const char* origin) {
  if (!config_error_.empty()) Tango::Except::throw_exception("IdmConfig", config_error_, origin);
  const std::string line = "AXIS" + std::to_string(axis_) + ":" + header;
  std::string reason, why;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    try {
      if (!client_) client_ = std::make_unique<client::Client>(address_, kTimeoutS);
      return client_->query(line);
    } catch (const client::DaemonError& e) {
      reason = "IdmdError";
      why = "idmd refused '" + line + "': " + e.what();
    } catch (const std::exception& e) {
      client_.reset();
      reason = "IdmdUnreachable";
      why = e.what();
    }
  }
  Tango::Except::throw_exception(reason, why, origin);
  return {};
}

void IdmAxis::command(const std::string& header, const char* origin) {
  if (!config_error_.empty()) Tango::Except::throw_exception("IdmConfig", config_error_, origin);
  const std::string line = "AXIS" + std::to_string(axis_) + ":" + header;
  std::string reason, why;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    try {
      if (!client_) client_ = std::make_unique<client::Client>(address_, kTimeoutS);
      client_->command(line);
      return;
    } catch (const client::DaemonError& e) {
      reason = "IdmdError";
      why = "idmd refused '" + line + "': " + e.what();
    } catch (const std::exception& e) {
      client_.reset();
      reason = "IdmdUnreachable";
      why = e.what();
    }
  }
  Tango::Except::throw_exception(reason, why, origin);
}

void IdmAxis::refresh() {
  if (!config_error_.empty()) return;
  std::lock_guard<std::mutex> lock(mutex_);
  try {
    if (!client_) client_ = std::make_unique<client::Client>(address_, kTimeoutS);
    status_ = client::parse_status(client_->query("AXIS" + std::to_string(axis_) + ":STAT?"));
    status_error_.clear();
  } catch (const client::DaemonError& e) {
    status_.reset();
    status_error_ =
        std::string("idmd refused STAT? of axis ") + std::to_string(axis_) + ": " + e.what();
  } catch (const std::exception& e) {
    client_.reset();
    status_.reset();
    status_error_ = std::string("idmd not reached: ") + e.what();
  }
}

void IdmAxis::apply_status() {
  std::optional<client::AxisStatus> s;
  std::string error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    s = status_;
    error = status_error_;
  }
  if (!config_error_.empty()) {
    set_state(Tango::FAULT);
    status_text_ = config_error_;
  } else if (!s) {
    set_state(Tango::FAULT);
    status_text_ = error;
  } else {
    const AxisState state = axis_state(*s);
    set_state(tango_state(state));
    status_text_ = axis_status_text(*s, state) + " (idmd at " + address_.text() + ", axis " +
                   std::to_string(axis_) + ")";
    // Position's write limits follow the soft limits (a write outside is refused by Tango).
    if (std::isfinite(s->lower_m) && std::isfinite(s->upper_m) && s->lower_m < s->upper_m &&
        (!limits_set_ || s->lower_m != limit_lo_ || s->upper_m != limit_hi_)) {
      try {
        Tango::WAttribute& w = get_device_attr()->get_w_attr_by_name("Position");
        // Never min >= max in between: the side that moves away from the other first.
        if (limits_set_ && s->lower_m >= limit_hi_) {
          w.set_max_value(s->upper_m);
          w.set_min_value(s->lower_m);
        } else {
          w.set_min_value(s->lower_m);
          w.set_max_value(s->upper_m);
        }
        limit_lo_ = s->lower_m;
        limit_hi_ = s->upper_m;
        limits_set_ = true;
      } catch (const Tango::DevFailed& e) {
        status_text_ += ", cannot set Position's limits: " + std::string(e.errors[0].desc.in());
      }
    }
  }
  set_status(status_text_);
}

void IdmAxis::publish() {
  Tango::Util* tg = Tango::Util::instance();
  if (tg->is_svr_starting() || tg->is_svr_shutting_down()) return;
  std::optional<client::AxisStatus> s;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    s = status_;
  }
  const AxisState state = !config_error_.empty() || !s ? AxisState::Fault : axis_state(*s);
  const bool changed = !last_state_known_ || state != last_state_;
  const bool was_moving = last_state_known_ && last_state_ == AxisState::Moving;
  last_state_ = state;
  last_state_known_ = true;
  if (changed) push_change_event("State");
  // Position while moving, and once more when the motion ends (the arrived position).
  if (s && s->position_valid && (state == AxisState::Moving || was_moving)) {
    event_position_ = s->position_m;
    timeval now{};
    gettimeofday(&now, nullptr);
    push_change_event("Position", &event_position_, now,
                      state == AxisState::Moving ? Tango::ATTR_CHANGING : Tango::ATTR_VALID);
  }
}

void IdmAxis::monitor_loop() {
  omni_thread::ensure_self self;  // Tango's monitor and event calls need an omni_thread
  while (!stopping_) {
    const auto next = std::chrono::steady_clock::now() + kMonitorPeriod;
    refresh();
    try {
      Tango::AutoTangoMonitor sync(this);
      if (stopping_) break;
      apply_status();
      publish();
    } catch (const Tango::DevFailed&) {
      // the device's monitor stayed busy (a long request, or the device being deleted): next round
    }
    while (!stopping_ && std::chrono::steady_clock::now() < next)
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

Tango::DevState IdmAxis::dev_state() {
  refresh();
  apply_status();
  return get_state();
}

Tango::ConstDevString IdmAxis::dev_status() {
  refresh();
  apply_status();
  return status_text_.c_str();
}

void IdmAxis::read_attr_hardware(std::vector<long>&) {
  refresh();
  apply_status();
}

void IdmAxis::read_Position(Tango::Attribute& att) {
  std::optional<client::AxisStatus> s;
  std::string error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    s = status_;
    error = status_error_;
  }
  if (!config_error_.empty())
    Tango::Except::throw_exception("IdmConfig", config_error_, "IdmAxis::read_Position");
  if (!s) Tango::Except::throw_exception("IdmdUnreachable", error, "IdmAxis::read_Position");
  if (!s->position_valid) {
    // No position to trust (no valid reading, beam or device lost): never the last good one.
    att.set_quality(Tango::ATTR_INVALID);
    return;
  }
  position_ = s->position_m;
  att.set_value(&position_);
  if (axis_state(*s) == AxisState::Moving) att.set_quality(Tango::ATTR_CHANGING);
}

void IdmAxis::write_Position(Tango::WAttribute& att) {
  Tango::DevDouble target = 0;
  att.get_write_value(target);
  command("MOVE:ABS " + number_text(target), "IdmAxis::write_Position");
  // The motion has started: State and the events say so at once.
  resync();
}

void IdmAxis::read_Target(Tango::Attribute& att) {
  target_ = client::parse_reply_number(query("MOVE?", "IdmAxis::read_Target"));
  att.set_value(&target_);
}

void IdmAxis::read_Referenced(Tango::Attribute& att) {
  std::optional<client::AxisStatus> s;
  std::string error;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    s = status_;
    error = status_error_;
  }
  if (!s)
    Tango::Except::throw_exception("IdmdUnreachable", error.empty() ? config_error_ : error,
                                   "IdmAxis::read_Referenced");
  referenced_ = s->referenced;
  att.set_value(&referenced_);
}

void IdmAxis::read_setting(Tango::Attribute& att, const std::string& header,
                           Tango::DevDouble& value, const char* origin) {
  value = client::parse_reply_number(query(header + "?", origin));
  att.set_value(&value);
}

void IdmAxis::write_setting(Tango::WAttribute& att, const std::string& header, const char* origin) {
  Tango::DevDouble v = 0;
  att.get_write_value(v);
  command(header + " " + number_text(v), origin);
}

void IdmAxis::read_Window(Tango::Attribute& att) {
  read_setting(att, "MOVE:WIND", window_, "IdmAxis::read_Window");
}

void IdmAxis::write_Window(Tango::WAttribute& att) {
  write_setting(att, "MOVE:WIND", "IdmAxis::write_Window");
}

void IdmAxis::read_Hold(Tango::Attribute& att) {
  read_setting(att, "HOLD", hold_, "IdmAxis::read_Hold");
}

void IdmAxis::write_Hold(Tango::WAttribute& att) {
  write_setting(att, "HOLD", "IdmAxis::write_Hold");
}

void IdmAxis::read_Velocity(Tango::Attribute& att) {
  read_setting(att, "MOVE:VEL", velocity_, "IdmAxis::read_Velocity");
}

void IdmAxis::write_Velocity(Tango::WAttribute& att) {
  write_setting(att, "MOVE:VEL", "IdmAxis::write_Velocity");
}

void IdmAxis::read_Offset(Tango::Attribute& att) {
  read_setting(att, "POS:OFFS", offset_, "IdmAxis::read_Offset");
}

void IdmAxis::write_Offset(Tango::WAttribute& att) {
  write_setting(att, "POS:OFFS", "IdmAxis::write_Offset");
  resync();  // the position and the soft limits (Position's min/max) moved with it
}

void IdmAxis::read_StatusBits(Tango::Attribute& att) {
  const std::uint64_t bits =
      client::parse_reply_count(query("STAT:OPER?", "IdmAxis::read_StatusBits"));
  status_bits_ = static_cast<Tango::DevLong>(bits & 0x7fffffff);
  att.set_value(&status_bits_);
}

// After a command: STATus? now, Tango's state and Position's limits from it, the events.
void IdmAxis::resync() {
  refresh();
  apply_status();
  publish();
}

void IdmAxis::stop() {
  command("STOP", "IdmAxis::Stop");
  resync();
}

void IdmAxis::reference() {
  command("REF", "IdmAxis::Reference");
  resync();
}

// n is sent as given, sign and all: idmd picks the direction from it.
void IdmAxis::step(Tango::DevLong cycles) {
  command("STEP " + std::to_string(cycles), "IdmAxis::Step");
  resync();
}

void IdmAxis::jog(bool positive) {
  command(positive ? "JOG POS" : "JOG NEG",
          positive ? "IdmAxis::JogPositive" : "IdmAxis::JogNegative");
  resync();
}

void IdmAxis::set_position(Tango::DevDouble position_m) {
  command("POS:SET " + number_text(position_m), "IdmAxis::SetPosition");
  resync();
}

// ---- The class: attributes, commands, devices ------------------------------------------------

namespace {

IdmAxis* axis_of(Tango::DeviceImpl* dev) {
  return static_cast<IdmAxis*>(dev);
}

// One attribute of the axis: read (and, with a writer, write) through the device's methods.
class AxisAttr : public Tango::Attr {
 public:
  using Reader = void (IdmAxis::*)(Tango::Attribute&);
  using Writer = void (IdmAxis::*)(Tango::WAttribute&);
  AxisAttr(const char* name, long type, Reader reader, Writer writer = nullptr)
      : Attr(name, type, writer != nullptr ? Tango::READ_WRITE : Tango::READ),
        reader_(reader),
        writer_(writer) {}
  void read(Tango::DeviceImpl* d, Tango::Attribute& a) override { (axis_of(d)->*reader_)(a); }
  void write(Tango::DeviceImpl* d, Tango::WAttribute& a) override {
    if (writer_ != nullptr) (axis_of(d)->*writer_)(a);
  }
  bool is_allowed(Tango::DeviceImpl*, Tango::AttReqType) override { return true; }

 private:
  Reader reader_;
  Writer writer_;
};

class StopCmd : public Tango::Command {
 public:
  StopCmd() : Command("Stop", Tango::DEV_VOID, Tango::DEV_VOID, "", "", Tango::OPERATOR) {}
  CORBA::Any* execute(Tango::DeviceImpl* d, const CORBA::Any&) override {
    axis_of(d)->stop();
    return new CORBA::Any();
  }
  bool is_allowed(Tango::DeviceImpl*, const CORBA::Any&) override { return true; }
};

class ReferenceCmd : public Tango::Command {
 public:
  ReferenceCmd()
      : Command("Reference", Tango::DEV_VOID, Tango::DEV_VOID, "", "", Tango::OPERATOR) {}
  CORBA::Any* execute(Tango::DeviceImpl* d, const CORBA::Any&) override {
    axis_of(d)->reference();
    return new CORBA::Any();
  }
  bool is_allowed(Tango::DeviceImpl*, const CORBA::Any&) override { return true; }
};

class StepCmd : public Tango::Command {
 public:
  StepCmd()
      : Command("Step", Tango::DEV_LONG, Tango::DEV_VOID,
                "cycles of an open-loop burst (idmd's STEP n): |n| cycles at the duty and "
                "frequency idmd picks (its map's largest-step cell); the sign of n alone picks "
                "the direction (positive: the positive direction), the duty is given as for the "
                "positive direction and mirrored for negative n",
                "", Tango::OPERATOR) {}
  CORBA::Any* execute(Tango::DeviceImpl* d, const CORBA::Any& in) override {
    Tango::DevLong cycles = 0;
    extract(in, cycles);
    axis_of(d)->step(cycles);
    return new CORBA::Any();
  }
  bool is_allowed(Tango::DeviceImpl*, const CORBA::Any&) override { return true; }
};

// JogPositive / JogNegative: a continuous move toward that soft limit, ended by Stop.
class JogCmd : public Tango::Command {
 public:
  explicit JogCmd(bool positive)
      : Command(positive ? "JogPositive" : "JogNegative", Tango::DEV_VOID, Tango::DEV_VOID, "", "",
                Tango::OPERATOR),
        positive_(positive) {}
  CORBA::Any* execute(Tango::DeviceImpl* d, const CORBA::Any&) override {
    axis_of(d)->jog(positive_);
    return new CORBA::Any();
  }
  bool is_allowed(Tango::DeviceImpl*, const CORBA::Any&) override { return true; }

 private:
  bool positive_;
};

class SetPositionCmd : public Tango::Command {
 public:
  SetPositionCmd()
      : Command("SetPosition", Tango::DEV_DOUBLE, Tango::DEV_VOID,
                "the position, m, that the current one becomes (idmd's POSition:SET): nothing "
                "moves, the user offset (attribute Offset) changes; at rest only",
                "", Tango::OPERATOR) {}
  CORBA::Any* execute(Tango::DeviceImpl* d, const CORBA::Any& in) override {
    Tango::DevDouble position_m = 0;
    extract(in, position_m);
    axis_of(d)->set_position(position_m);
    return new CORBA::Any();
  }
  bool is_allowed(Tango::DeviceImpl*, const CORBA::Any&) override { return true; }
};

Tango::Attr* with_properties(Tango::Attr* attr, const char* unit, const char* description,
                             const char* format) {
  Tango::UserDefaultAttrProp p;
  if (*unit) p.set_unit(unit);
  p.set_description(description);
  if (*format) p.set_format(format);
  attr->set_default_properties(p);
  return attr;
}

}  // namespace

IdmAxisClass* IdmAxisClass::instance_ = nullptr;

IdmAxisClass::IdmAxisClass(std::string& name) : Tango::DeviceClass(name) {}

IdmAxisClass* IdmAxisClass::init(const char* name) {
  if (!instance_) {
    std::string s(name);
    instance_ = new IdmAxisClass(s);
  }
  return instance_;
}

IdmAxisClass* IdmAxisClass::instance() {
  if (!instance_) {
    std::fprintf(stderr, "IdmAxisClass is not initialised\n");
    std::abort();
  }
  return instance_;
}

void IdmAxisClass::command_factory() {
  command_list.push_back(new StopCmd());
  command_list.push_back(new ReferenceCmd());
  command_list.push_back(new StepCmd());
  command_list.push_back(new JogCmd(true));
  command_list.push_back(new JogCmd(false));
  command_list.push_back(new SetPositionCmd());
}

void IdmAxisClass::attribute_factory(std::vector<Tango::Attr*>& attrs) {
  attrs.push_back(with_properties(new AxisAttr("Position", Tango::DEV_DOUBLE,
                                               &IdmAxis::read_Position, &IdmAxis::write_Position),
                                  "m",
                                  "Position of the axis (write: a closed-loop move there); "
                                  "min/max are the daemon's soft limits",
                                  "%.9e"));
  attrs.push_back(with_properties(new AxisAttr("Target", Tango::DEV_DOUBLE, &IdmAxis::read_Target),
                                  "m", "Target of the last move", "%.9e"));
  attrs.push_back(
      with_properties(new AxisAttr("Referenced", Tango::DEV_BOOLEAN, &IdmAxis::read_Referenced), "",
                      "The axis is referenced", ""));
  attrs.push_back(with_properties(
      new AxisAttr("Window", Tango::DEV_DOUBLE, &IdmAxis::read_Window, &IdmAxis::write_Window), "m",
      "In-position window (MOVE:WINDow)", "%.3e"));
  attrs.push_back(with_properties(
      new AxisAttr("Hold", Tango::DEV_DOUBLE, &IdmAxis::read_Hold, &IdmAxis::write_Hold), "s",
      "Hold after the moves that follow (HOLD; 0 none, -1 until "
      "the next motion)",
      "%.3f"));
  attrs.push_back(with_properties(new AxisAttr("Velocity", Tango::DEV_DOUBLE,
                                               &IdmAxis::read_Velocity, &IdmAxis::write_Velocity),
                                  "m/s",
                                  "Speed limit of the moves and jogs that follow (MOVE:VELocity; 0 "
                                  "no limit)",
                                  "%.3e"));
  attrs.push_back(with_properties(
      new AxisAttr("Offset", Tango::DEV_DOUBLE, &IdmAxis::read_Offset, &IdmAxis::write_Offset), "m",
      "User offset (POSition:OFFSet): Position, Target and the soft limits are the axis's own "
      "plus it",
      "%.9e"));
  attrs.push_back(
      with_properties(new AxisAttr("StatusBits", Tango::DEV_LONG, &IdmAxis::read_StatusBits), "",
                      "STATus:OPERation?: 0 moving, 1 in position, 2 holding, 3 "
                      "referenced, 4/5 at lower/upper soft limit, 6 end of travel, 7 "
                      "fault, 8 position valid, 9 referencing",
                      ""));
}

void IdmAxisClass::device_factory(const Tango::DevVarStringArray* devlist) {
  for (unsigned long i = 0; i < devlist->length(); ++i)
    device_list.push_back(new IdmAxis(this, (*devlist)[i].in()));
  for (unsigned long i = 1; i <= devlist->length(); ++i) {
    auto* dev = static_cast<IdmAxis*>(device_list[device_list.size() - i]);
    if (Tango::Util::_UseDb && !Tango::Util::_FileDb)
      export_device(dev);
    else
      export_device(dev, dev->get_name().c_str());
  }
}

}  // namespace idm::tango
