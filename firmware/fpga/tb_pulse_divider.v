// pulse_divider alone under a cycle stimulus read from a file (+stim=<file>), lines
//   <first posedge> <cycle>     (increasing posedges, the first one 1)
// The value is applied at the negedge before that posedge.  Prints
//   E <posedge index> <clkout>  for every output edge; runs +p_end=<n> posedges;
// +vcd=<file> dumps a VCD (clk, cycle, creg, count, clkout: Yang Fig. 6).
`timescale 1ns/1ps
module tb_pulse_divider;
    reg clk = 1'b0, reset_n = 1'b1;
    reg [31:0] cycle = 32'd0;
    wire clkout;
    wire [31:0] count;
    reg [1023:0] stim, vcd;
    integer fd, r, p_end, next_p, next_v;
    integer pcount = 0;
    reg last_out = 1'b0;

    pulse_divider dut (.clk(clk), .reset_n(reset_n), .cycle(cycle), .clkout(clkout), .count(count));

    always #10 clk = ~clk;

    initial begin
        if (!$value$plusargs("stim=%s", stim)) stim = "stim.txt";
        if (!$value$plusargs("p_end=%d", p_end)) p_end = 200;
        if ($value$plusargs("vcd=%s", vcd)) begin
            $dumpfile(vcd);
            $dumpvars(0, tb_pulse_divider);
        end
        fd = $fopen(stim, "r");
        if (fd == 0) begin
            $display("cannot open stimulus file");
            $finish;
        end
        r = $fscanf(fd, "%d %d\n", next_p, next_v);
        while (r == 2 && next_p <= 1) begin
            cycle = next_v;
            r = $fscanf(fd, "%d %d\n", next_p, next_v);
        end
        #1 reset_n = 1'b0;
        #1 reset_n = 1'b1;
    end

    always @(posedge clk) pcount = pcount + 1;

    always @(negedge clk) begin
        if (clkout != last_out) begin
            $display("E %0d %0d", pcount, clkout);
            last_out = clkout;
        end
        while (r == 2 && next_p == pcount + 1) begin
            cycle = next_v;
            r = $fscanf(fd, "%d %d\n", next_p, next_v);
        end
        if (pcount >= p_end) $finish;
    end
endmodule
