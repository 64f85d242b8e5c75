-- MRFT relay inside ArduCopter (mrft-ident, issue 41): a Lua applet for GUIDED mode.
--
-- Set MRFT_AXIS to 1 (altitude), 2 (roll) or 3 (pitch) while hovering in GUIDED: the script runs one
-- Modified Relay Feedback Test on that loop for MRFT_DUR seconds, then hands the vehicle back to
-- GUIDED's velocity hold and sets MRFT_AXIS back to 0.
--
-- The rule (mrftcli/mrft/relays.py, docs/method.md): e = r - y. While +h, track e_max since the last
-- switch and switch to -h when e_max > 0 and e <= -beta e_max; while -h, track e_min and switch to +h
-- when e_min < 0 and e >= -beta e_min. The first half-cycle keeps the sign of the first error until
-- the error passes MRFT_ETH on the other side.
--
-- Altitude: the relay acts on the throttle around hover (MOT_THST_HOVER at the start), through
--   vehicle:set_target_rate_and_throttle with zero body rates (ArduPilot's attitude loops hold level);
--   the centre is the throttle of GUIDED's hold averaged over the second before the test;
--   y = the EKF's altitude above home [m].
-- Roll / pitch: the relay acts on the axis's mixer input (the paper's inner-loop test: attitude error
--   -> relay -> torque). Lua has no binding to the mixer or to the System ID mode's injection (which
--   plays a fixed chirp), so for the test the script makes the axis's rate PID a unit feed-forward
--   (ATC_RAT_xxx_P = I = D = 0, FF = 1, ATC_ANG_xxx_P = 0, ATC_ACCEL_x_MAX = 0: the rate PID's output,
--   i.e. the mixer input, is then the rate target in rad/s) and commands the relay as that axis's
--   body rate; the other axes keep ArduPilot's control, and a PD on the EKF altitude holds height
--   through the throttle. The parameters are restored when the test ends. y = the EKF's roll or pitch [rad].
-- MRFT_DLY [ms] delays what is sent (the +20 ms test), after the relay decides: a FIFO in simulated time sends
-- the newest decision at least MRFT_DLY old at each tick (the log's Snt against Cmd shows the delay achieved).
--
-- MRFT_MAIN 1: the relay runs in the vehicle's main loop instead (scripts/sitl/ardupilot_patch, applied
-- by build_ardupilot.sh: a task after the flight mode, at the loop rate, in the simulation's lockstep;
-- MRFT_DLY in whole ticks). This script then only prepares the test (the centre in MRFT_BIAS, the opened
-- rate loop), raises MRFT_GO to the axis, keeps GUIDED's target fresh (the throttle centre, or the
-- altitude PD for roll / pitch) and lowers MRFT_GO at the end; the firmware writes MRFT and confirms by
-- MRFT_RUN = 1 (a firmware without the patch does not, and the test stops with a message saying so).
--
-- Logged every tick as DataFlash message MRFT (mrft-ident's `ardupilot-mrft` layout):
--   Ax axis (1 alt, 2 roll, 3 pitch), Cmd the relay's decision + bias [throttle or mixer units],
--   Snt what was sent after the delay FIFO, Out the loop output [m or rad], SP the setpoint,
--   Rel the relay sign (+1/-1), B beta, H relay height, Bias the bias, Dly the delay [s];
-- and once at each test's start as MRFB (Ax, B, H, Bias, Dly, Hov: the hover throttle GUIDED used just before):
-- the beta the reader takes.

local TABLE_KEY = 41
local PERIOD_MS = 2
assert(param:add_table(TABLE_KEY, "MRFT_", 13), "MRFT: could not add the parameter table")
local function add(idx, name, default)
  assert(param:add_param(TABLE_KEY, idx, name, default), "MRFT: could not add MRFT_" .. name)
  return Parameter("MRFT_" .. name)
end
local P_AXIS = add(1, "AXIS", 0)
local P_BETA = add(2, "BETA", -0.3)
local P_H = add(3, "H", 0.05)
local P_DUR = add(4, "DUR", 15)
local P_DLY = add(5, "DLY", 0)
local P_ETH = add(6, "ETH", 0)
local P_ZKP = add(7, "ZKP", 0.08)
local P_ZKD = add(8, "ZKD", 0.08)
local P_TICK = add(9, "TICK", 1)
local P_GO = add(10, "GO", 0)
local P_BIAS = add(11, "BIAS", 0)
local P_RUN = add(12, "RUN", 0)
local P_MAIN = add(13, "MAIN", 0)

local GUIDED = 4
local AXIS_PARAMS = {
  [2] = { "ATC_RAT_RLL_P", "ATC_RAT_RLL_I", "ATC_RAT_RLL_D", "ATC_RAT_RLL_FF", "ATC_ANG_RLL_P", "ATC_ACCEL_R_MAX" },
  [3] = { "ATC_RAT_PIT_P", "ATC_RAT_PIT_I", "ATC_RAT_PIT_D", "ATC_RAT_PIT_FF", "ATC_ANG_PIT_P", "ATC_ACCEL_P_MAX" },
}
local OPEN_VALUES = { 0, 0, 0, 1, 0, 0 }

local test = nil  -- the running test's state
local hover_avg = nil  -- the throttle while hovering between tests, averaged over about 1 s
local hover_us = 0

local function altitude()
  local down = ahrs:get_relative_position_D_home()
  if down == nil then return nil end
  return -down
end

local function climb_rate()
  local v = ahrs:get_velocity_NED()
  if v == nil then return 0 end
  return -v:z()
end

local function output(axis)
  if axis == 1 then return altitude() end
  if axis == 2 then return ahrs:get_roll_rad() end
  return ahrs:get_pitch_rad()
end

local function set_params(names, values)
  for i, name in ipairs(names) do
    assert(param:set(name, values[i]), "MRFT: could not set " .. name)
  end
end

local function start(axis)
  -- the relay's centre: the throttle GUIDED's position hold used just before (MOT_THST_HOVER is the
  -- learned value saved at disarm, not the live one)
  local hover = hover_avg or param:get("MOT_THST_HOVER")
  local y = output(axis)
  if hover == nil or y == nil then return nil end
  local t = {
    axis = axis, beta = P_BETA:get(), h = P_H:get(), dly = P_DLY:get(), eth = P_ETH:get(),
    t0 = millis():tofloat(), hover = hover, z0 = altitude(), fifo = {}, saved = nil, last_us = -1,
    sp = (axis == 1) and y or 0.0, relay = 1, e_ext = 0, first_half = true, started = false,
    main = P_MAIN:get() >= 0.5,
  }
  t.bias = (axis == 1) and hover or 0.0
  if AXIS_PARAMS[axis] then
    t.saved = {}
    for i, name in ipairs(AXIS_PARAMS[axis]) do t.saved[i] = param:get(name) end
    set_params(AXIS_PARAMS[axis], OPEN_VALUES)
  end
  if t.main then
    -- the firmware's task takes beta, h, the delay and the start threshold from MRFT_* when MRFT_GO rises
    P_RUN:set(0); P_BIAS:set(t.bias); P_GO:set(axis)
  end
  -- one MRFB message per test, at its start: beta, h and the delay (the reader's beta topic)
  logger:write("MRFB", "Ax,B,H,Bias,Dly,Hov", "Bfffff", "----s-", "------", axis, t.beta, t.h, t.bias, t.dly * 0.001,
    t.hover)
  gcs:send_text(6, string.format("MRFT: axis %d beta %.2f h %.3f delay %d ms", axis, t.beta, t.h, t.dly))
  return t
end

local function stop(t, why)
  -- a last sample with the relay off (the command back at its centre) closes the test in the log
  if t.main then
    P_GO:set(0)  -- the firmware's task writes the closing sample
  else
    local y = output(t.axis) or t.sp
    logger:write("MRFT", "Ax,Cmd,Snt,Out,SP,Rel,B,H,Bias,Dly", "Bffffbffff", "--------s-", "----------",
      t.axis, t.bias, t.bias, y, t.sp, 0, t.beta, t.h, t.bias, t.dly * 0.001)
  end
  if t.saved then set_params(AXIS_PARAMS[t.axis], t.saved) end
  vehicle:set_target_velocity_NED(Vector3f())
  P_AXIS:set(0)
  gcs:send_text(6, "MRFT: test ended (" .. why .. ")")
end

-- the switching rule (mrftcli/mrft/relays.py, RelayLaw.sampled)
local function relay_step(t, e)
  if not t.started then
    t.relay = (e >= 0) and 1 or -1
    t.e_ext = e
    t.started = true
  elseif t.first_half then
    if t.relay * e < -t.eth then
      t.relay = -t.relay; t.e_ext = e; t.first_half = false
    end
  elseif t.relay > 0 then
    if e > t.e_ext then t.e_ext = e end
    if t.e_ext > 0 and e <= -t.beta * t.e_ext then t.relay = -1; t.e_ext = e end
  else
    if e < t.e_ext then t.e_ext = e end
    if t.e_ext < 0 and e >= -t.beta * t.e_ext then t.relay = 1; t.e_ext = e end
  end
  return t.relay
end

-- with the main-loop relay: keep GUIDED's angle-and-thrust target fresh (the task overrides the axis)
local function hold(t)
  if millis():tofloat() - t.t0 > 500 and P_RUN:get() < 0.5 then return false end
  if t.axis == 1 then
    vehicle:set_target_rate_and_throttle(0, 0, 0, t.bias)
  else
    local z = altitude() or t.z0
    vehicle:set_target_rate_and_throttle(0, 0, 0, t.hover + P_ZKP:get() * (t.z0 - z) - P_ZKD:get() * climb_rate())
  end
  return true
end

local function tick(t)
  -- SITL runs this thread beside the simulation, not in its lockstep: act at most every MRFT_TICK ms
  -- of simulated time (11 ms: the thread's usual 5.8 ms steps, twice, so that its ticks are regular)
  local now_us = micros():tofloat()
  if now_us - t.last_us < P_TICK:get() * 1000 - 500 then return true end
  t.last_us = now_us
  local y = output(t.axis)
  if y == nil then return false end
  local cmd = t.bias + t.h * relay_step(t, t.sp - y)
  -- the delay FIFO, in simulated time: send the newest decision at least MRFT_DLY old
  table.insert(t.fifo, { now_us, cmd })
  local limit = now_us - t.dly * 1000
  while #t.fifo > 1 and t.fifo[2][1] <= limit do table.remove(t.fifo, 1) end
  local sent = t.bias
  if t.fifo[1][1] <= limit then sent = t.fifo[1][2] end
  if t.axis == 1 then
    vehicle:set_target_rate_and_throttle(0, 0, 0, sent)
  else
    local z = altitude() or t.z0
    local thr = t.hover + P_ZKP:get() * (t.z0 - z) - P_ZKD:get() * climb_rate()
    local rate_dps = math.deg(sent)  -- FF = 1: the mixer input equals the rate target in rad/s
    if t.axis == 2 then
      vehicle:set_target_rate_and_throttle(rate_dps, 0, 0, thr)
    else
      vehicle:set_target_rate_and_throttle(0, rate_dps, 0, thr)
    end
  end
  logger:write("MRFT", "Ax,Cmd,Snt,Out,SP,Rel,B,H,Bias,Dly", "Bffffbffff", "--------s-", "----------",
    t.axis, cmd, sent, y, t.sp, t.relay, t.beta, t.h, t.bias, t.dly * 0.001)
  return true
end

local function update()
  local axis = math.floor(P_AXIS:get() + 0.5)
  if test == nil then
    if arming:is_armed() and vehicle:get_mode() == GUIDED then
      local thr, now = motors:get_throttle(), micros():tofloat()
      local a = math.min(1.0, math.max(0.0, (now - hover_us) * 1e-6))
      hover_avg = (hover_avg == nil) and thr or hover_avg + a * (thr - hover_avg)
      hover_us = now
    else
      hover_avg = nil
    end
    if axis >= 1 and axis <= 3 and hover_avg ~= nil then
      test = start(axis)
    end
    return update, PERIOD_MS
  end
  if axis ~= test.axis then stop(test, "MRFT_AXIS changed"); test = nil; return update, PERIOD_MS end
  if not arming:is_armed() or vehicle:get_mode() ~= GUIDED then
    stop(test, "disarmed or left GUIDED"); test = nil; return update, PERIOD_MS
  end
  if millis():tofloat() - test.t0 > P_DUR:get() * 1000 then stop(test, "duration"); test = nil; return update, PERIOD_MS end
  if test.main then
    if not hold(test) then
      stop(test, "no main-loop relay in this firmware (MRFT_RUN stayed 0): build with scripts/sitl/build_ardupilot.sh")
      test = nil
    end
  elseif not tick(test) then stop(test, "no estimate"); test = nil end
  return update, PERIOD_MS
end

gcs:send_text(6, "MRFT relay script loaded")
return update, PERIOD_MS
