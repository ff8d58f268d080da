/* The emulator's plant channel: the HAL (nfal_hal.h) of the emulated rig, served over one byte stream.
 *
 * In emulation the rig's hardware is the Python emulator's truth (hil/plant_channel.py is the other end):
 * it paces the ticks, and each tick asks the firmware for its drive and answers with the sensors. Records
 * (little-endian, no framing: the stream is reliable):
 *
 *   emulator -> firmware                                  firmware -> emulator
 *   'C' sample_us watchdog_us ramp_us heartbeat_us        'R' ok u8 (1: config taken)
 *       (u32 each) max_drive_voltage f32 tunnel u8
 *   'T' n u16, n bytes (tunnel: the host's bytes)         'D' volts f32 (hal_drive_write)
 *   'S' height f32 frequency f32 flags u8                 'E' cost u32, status u16, applied f32,
 *       (flags: 1 locked, 2 resting, 4 out of range)          command_seq u32, state u8 (1 armed,
 *                                                             2 ramping), n u16, n bytes (tunnel: the
 *                                                             rig's bytes)
 *   'K'                                                   'k' 13 x u32: the 9 counters, rx_overflow,
 *                                                             tx_dropped, the largest tick cost, frames sent
 *
 * Tunnel mode carries the protocol's bytes in 'T' and 'E' (exact, tick by tick: the conformance tests);
 * otherwise they go on the platform's serial line (a pty, QEMU's UART0). cost is the tick's own work in
 * the platform's cycle counter (ns on the host, SysTick counts in QEMU), without the wait for 'S'.
 */
#ifndef NFAL_PLANT_H
#define NFAL_PLANT_H

#include <stddef.h>
#include <stdint.h>

#include "nfal_fw.h"

/* What a platform provides to the plant server. */
void plat_plant_read(uint8_t *p, size_t n);       /* blocking, exactly n bytes */
void plat_plant_write(const uint8_t *p, size_t n); /* blocking, all of them */
void plat_serial_poll(nfal_fw *fw);               /* serial mode: what the line holds -> nfal_fw_rx */
size_t plat_serial_send(const uint8_t *p, size_t n); /* serial mode: queue, never block; returns bytes taken */
uint32_t plat_cycles(void);                       /* free-running counter (wraps) */

/* Serve the plant channel forever (returns only if plat_plant_read gives up). */
void nfal_plant_serve(void);

#endif
