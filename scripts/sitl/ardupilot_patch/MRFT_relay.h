// mrft-ident (issue 41): the MRFT switching rule and a delay line in whole loop ticks.
// Free of ArduPilot headers so that tests/test_sitl_main_loop_relay.py can compile and check it alone.
#pragma once

#include <stdint.h>

namespace mrft {

// The rule of mrftcli/mrft/relays.py (RelayLaw.sampled): e = r - y; while +h, track e_max since the last
// switch and switch to -h when e_max > 0 and e <= -beta e_max; symmetrically while -h. The first
// half-cycle keeps the first error's sign until the error passes eth on the other side.
struct Relay {
    float beta = -0.3f;
    float eth = 0.0f;
    int8_t sign = 1;
    float e_ext = 0.0f;
    bool started = false;
    bool first_half = true;

    void reset(float beta_in, float eth_in) {
        beta = beta_in; eth = eth_in; sign = 1; e_ext = 0.0f; started = false; first_half = true;
    }

    int8_t step(float e) {
        if (!started) {
            sign = (e >= 0.0f) ? 1 : -1; e_ext = e; started = true;
        } else if (first_half) {
            if (sign * e < -eth) { sign = -sign; e_ext = e; first_half = false; }
        } else if (sign > 0) {
            if (e > e_ext) { e_ext = e; }
            if (e_ext > 0.0f && e <= -beta * e_ext) { sign = -1; e_ext = e; }
        } else {
            if (e < e_ext) { e_ext = e; }
            if (e_ext < 0.0f && e >= -beta * e_ext) { sign = 1; e_ext = e; }
        }
        return sign;
    }
};

// What was pushed `ticks` calls ago (`idle` until that many have been pushed): a delay of exactly
// ticks / loop rate, as the main loop runs once per tick.
template <uint16_t N>
struct DelayLine {
    float buf[N] {};
    uint16_t head = 0;
    uint16_t count = 0;
    uint16_t ticks = 0;
    float idle = 0.0f;

    void reset(uint16_t delay_ticks, float idle_value) {
        ticks = (delay_ticks < N) ? delay_ticks : uint16_t(N - 1);
        idle = idle_value; head = 0; count = 0;
    }

    float push(float x) {
        buf[head] = x;
        head = uint16_t((head + 1) % N);
        if (count < N) { count++; }
        if (count <= ticks) { return idle; }
        return buf[(head + 2 * N - 1 - ticks) % N];
    }
};

}  // namespace mrft
