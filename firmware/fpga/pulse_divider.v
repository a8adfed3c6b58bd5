// Pulse divider of Yang et al. (2013), "PWM model" (their Fig. 5 and listing), 50 % duty.
//
// The paper's listing compares `count == compare_reg` against a compare_reg that the
// speed generator changes every refresh period (200 us), while one pulse period lasts
// 1 ms .. 143 ms.  When the new, shorter cycle falls below the running count the
// equality never holds again and the 32-bit counter runs through 2^32 clocks (86 s at
// 50 MHz) before the next edge (jerklab.fpga.published_divider_lockup finds the first
// such refresh of the paper's move at t = 0.155 s).  The commented-out
// `compare_reg_refresh_flag` of the listing points at the fix used here: the cycle is
// latched (creg) only at the end of a period, and the end test is `>=`.
//
// Per posedge (mirrored clock-exactly by jerklab.fpga.divider_edges):
//   idle (creg == 0):     clkout <= 0, count <= 0, creg <= cycle
//   count == creg >> 1:   clkout <= 1, count <= count + 1          (rising edge)
//   count >= creg:        clkout <= 0, count <= 1, creg <= cycle   (falling edge)
//   otherwise:            count <= count + 1
// A period latched at posedge q rises at q + creg/2 and falls at q + creg.
`timescale 1ns/1ps
module pulse_divider (
    input  wire        clk,
    input  wire        reset_n,     // asynchronous, active low (as in the paper)
    input  wire [31:0] cycle,       // clocks per output pulse (f_clk / f), 0 = stop
    output reg         clkout,
    output reg  [31:0] count
);
    reg  [31:0] creg;               // latched cycle of the running period
    wire [31:0] duty = creg >> 1;   // "compare_reg/2": 50 % duty

    always @(posedge clk or negedge reset_n) begin
        if (!reset_n) begin
            clkout <= 1'b0;
            count  <= 32'd0;
            creg   <= 32'd0;
        end else if (creg == 32'd0) begin
            clkout <= 1'b0;
            count  <= 32'd0;
            creg   <= cycle;
        end else if (count == duty) begin
            clkout <= 1'b1;
            count  <= count + 32'd1;
        end else if (count >= creg) begin
            clkout <= 1'b0;
            count  <= 32'd1;
            creg   <= cycle;
        end else begin
            count  <= count + 32'd1;
        end
    end
endmodule
