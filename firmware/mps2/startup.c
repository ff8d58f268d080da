/* Reset and vectors for the Cortex-M4F: copy .data, clear .bss, switch the FPU on, run main. */
#include <stdint.h>

extern uint32_t _data_load, _data_start, _data_end, _bss_start, _bss_end, _stack_top;
int main(void);
void reset_handler(void);
void default_handler(void);
void systick_handler(void);
void uart0_rx_handler(void);
void uart0_tx_handler(void);
void uart1_rx_handler(void);

void default_handler(void) {
    for (;;) {
    }
}

void reset_handler(void) {
    uint32_t *src = &_data_load, *dst = &_data_start;
    while (dst < &_data_end) *dst++ = *src++;
    for (dst = &_bss_start; dst < &_bss_end;) *dst++ = 0;
    *(volatile uint32_t *)0xE000ED88u |= 0xFu << 20; /* CPACR: CP10 and CP11 full access (the FPU) */
    __asm__ volatile("dsb\n isb");
    main();
    for (;;) {
    }
}

/* The core exceptions (SysTick extends the cycle counter) and the first three interrupts: UART0 RX, UART0 TX,
 * UART1 RX. */
__attribute__((section(".vectors"), used)) static void (*const vectors[16 + 3])(void) = {
    (void (*)(void))(uintptr_t)&_stack_top, reset_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, 0, 0, 0, 0, default_handler, default_handler, 0,
    default_handler, systick_handler,
    uart0_rx_handler, uart0_tx_handler, uart1_rx_handler};
